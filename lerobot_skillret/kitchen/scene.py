"""The robosuite kitchen scene: a Panda (OSC_POSE, 7-D action) at a table with the project's own fixtures.

All task-relevant state (object poses, drawer and switch joints) is MuJoCo state, so `get_sim_state` /
`set_sim_state` reproduce a scene exactly. Observations are built by `observations.py`, not by robosuite's
observables (turned off here: they cost time every substep and would be a second source of truth).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import OrderedDict
from pathlib import Path

import numpy as np
import robosuite.macros as macros
from robosuite.controllers import load_composite_controller_config
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv
from robosuite.models.arenas import TableArena
from robosuite.models.tasks import ManipulationTask
from robosuite.utils.mjcf_utils import array_to_string

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen.observations import FIXTURE_JOINTS

# One simulation timestep for generation and evaluation (layout.SIMULATION_TIMESTEP), applied here only.
macros.SIMULATION_TIMESTEP = layout.SIMULATION_TIMESTEP

ASSETS = Path(__file__).parent / "assets"
# (asset file, body name in the file, name prefix for templated assets, fixture key in layout.FIXTURES)
_FIXTURE_ASSETS = (
    ("drawer.xml", "drawer_housing", "", "drawer"),
    ("switch.xml", "P_switch", "light_", "light"),
    ("switch.xml", "P_switch", "burner_", "burner"),
    ("lamp.xml", "lamp", "", "lamp"),
    ("stove.xml", "stove", "", "stove"),
    ("serving.xml", "serving", "", "serving"),
    ("shelf.xml", "shelf", "", "shelf"),
)
ROBOT_INIT_NOISE = 0.02  # rad, per arm joint, drawn from the scene's own rng (robosuite's uses np.random)


def _load_asset(fname: str, prefix: str) -> ET.Element:
    text = (ASSETS / fname).read_text()
    if prefix:
        text = text.replace("P_", prefix)
    return ET.fromstring(text)


class KitchenScene(ManipulationEnv):
    """Panda kitchen table. Reset with `reset_to(layout_spec)`; the scene never randomises by itself."""

    def __init__(self, render_collision_mesh: bool = True):
        self.table_full_size = layout.TABLE_FULL_SIZE
        self.table_offset = np.array((0.0, 0.0, layout.TABLE_Z))
        super().__init__(
            robots="Panda",
            controller_configs=load_composite_controller_config(robot="Panda"),
            initialization_noise=None,
            use_camera_obs=False,
            has_renderer=False,
            has_offscreen_renderer=False,  # images come from rendering.CameraRenderer
            render_collision_mesh=render_collision_mesh,
            control_freq=layout.CONTROL_FREQ,
            horizon=10**9,
            ignore_done=True,
            hard_reset=False,
        )
        self._cache_ids()

    # ----- model -----
    def _load_model(self):
        super()._load_model()
        robot = self.robots[0]
        base = np.array(robot.robot_model.base_xpos_offset["table"](self.table_full_size[0]))
        robot.robot_model.set_base_xpos([layout.ROBOT_BASE_X, base[1], base[2]])
        arena = TableArena(
            table_full_size=self.table_full_size, table_friction=(1.0, 0.005, 0.0001), table_offset=self.table_offset
        )
        arena.set_origin([0, 0, 0])
        for fname, body_name, prefix, key in _FIXTURE_ASSETS:
            root = _load_asset(fname, prefix)
            body = root.find("./worldbody/body")
            assert body is not None and body.get("name") == body_name.replace("P_", prefix), fname
            x, y = layout.FIXTURES[key]
            lift = layout.DRAWER_LIFT if key == "drawer" else 0.0
            body.set("pos", array_to_string([x, y, layout.TABLE_Z + lift]))
            arena.worldbody.append(body)
        # A close overview camera for pictures and videos of the work area.
        ET.SubElement(
            arena.worldbody, "camera", name="overview", mode="targetbody", target="serving", pos="0.55 0 1.85"
        )
        for fname in ("items.xml", "vessels.xml"):
            for body in _load_asset(fname, "").find("./worldbody"):
                if body.get("name") in layout.ITEMS:  # item sizes live in layout.ITEMS only
                    geom, (hx, _hy, hz) = body.find("geom"), layout.ITEMS[body.get("name")].half
                    size = [hx, hz] if geom.get("type") == "cylinder" else layout.ITEMS[body.get("name")].half
                    geom.set("size", array_to_string(size))
                arena.worldbody.append(body)
        self.model = ManipulationTask(mujoco_arena=arena, mujoco_robots=[robot.robot_model for robot in self.robots])
        # Several contact points per convex pair (MuJoCo's multiccd). With the default single point, a box resting
        # on a cylinder (the bread on the plate, a vessel on the burner) sinks ~5 mm into it and spins in place for
        # as long as it rests there: an orientation play data never shows, out of the prior skills' range.
        ET.SubElement(self.model.root.find("option"), "flag", multiccd="enable")

    def _setup_observables(self):
        return OrderedDict()

    def _cache_ids(self):
        m = self.sim.model
        self.body_ids = {name: m.body_name2id(name) for name in layout.MOVABLES}
        self.body_ids["drawer_tray"] = m.body_name2id("drawer_tray")
        self.free_qpos = {name: m.get_joint_qpos_addr(f"{name}_joint")[0] for name in layout.MOVABLES}
        self.free_qvel = {name: m.get_joint_qvel_addr(f"{name}_joint")[0] for name in layout.MOVABLES}
        self.fixture_qpos = {j: m.get_joint_qpos_addr(j) for j in FIXTURE_JOINTS}
        self._bulb = m.geom_name2id("lamp_bulb")
        self._indicator = m.geom_name2id("stove_indicator")
        robot = self.robots[0]
        self.eef_site = robot.eef_site_id["right"]
        self.gripper_qpos_idx = list(robot._ref_gripper_joint_pos_indexes["right"])
        self.arm_qpos_idx = list(robot._ref_joint_pos_indexes)

    # ----- state access -----
    def body_pos(self, name: str) -> np.ndarray:
        return np.array(self.sim.data.body_xpos[self.body_ids[name]])

    def body_quat(self, name: str) -> np.ndarray:
        """Orientation as (w, x, y, z) (MuJoCo order)."""
        return np.array(self.sim.data.body_xquat[self.body_ids[name]])

    def joint(self, name: str) -> float:
        return float(self.sim.data.qpos[self.fixture_qpos[name]])

    def eef_pos(self) -> np.ndarray:
        return np.array(self.sim.data.site_xpos[self.eef_site])

    def eef_mat(self) -> np.ndarray:
        return np.array(self.sim.data.site_xmat[self.eef_site]).reshape(3, 3)

    def gripper_qpos(self) -> np.ndarray:
        return np.array(self.sim.data.qpos[self.gripper_qpos_idx])

    def get_sim_state(self) -> np.ndarray:
        return np.array(self.sim.get_state().flatten())

    def set_sim_state(self, state: np.ndarray) -> None:
        """Restore a flat MuJoCo state (time, qpos, qvel) saved by `get_sim_state`."""
        self.sim.set_state_from_flattened(np.asarray(state, dtype=np.float64))
        self._cold_start()

    def _cold_start(self) -> None:
        """Clear the solver warm start (not part of the saved state) so a restored state steps identically."""
        self.sim.data.qacc_warmstart[:] = 0.0
        self.sim.forward()
        # The OSC controller caches the eef pose and goal (Python state): refresh them from the restored sim.
        controller = self.robots[0].composite_controller
        controller.update_state()
        for arm in controller.arms:
            controller.part_controllers[arm].update(force=True)
            controller.part_controllers[arm].reset_goal()
        self._refresh_indicators()

    # ----- reset / step -----
    def reset_to(
        self, poses: dict[str, tuple[float, float, float, float]], joints: dict[str, float], rng: np.random.Generator
    ) -> None:
        """Reset the robot (small joint noise from `rng`) and put every movable at (x, y, z, yaw)."""
        self.reset()
        qpos = self.sim.data.qpos
        qpos[self.arm_qpos_idx] += rng.normal(0.0, ROBOT_INIT_NOISE, len(self.arm_qpos_idx))
        for name in layout.MOVABLES:
            x, y, z, yaw = poses[name]
            adr = self.free_qpos[name]
            qpos[adr : adr + 7] = [x, y, z, np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
            self.sim.data.qvel[self.free_qvel[name] : self.free_qvel[name] + 6] = 0.0
        for jname in FIXTURE_JOINTS:
            qpos[self.fixture_qpos[jname]] = joints[jname]
        self.sim.data.qvel[:] = 0.0
        self.sim.forward()
        # Let objects settle onto their surfaces with the arm held still.
        for _ in range(5):
            self.step(np.zeros(7))
        self._cold_start()

    def step(self, action):
        out = super().step(action)
        self._refresh_indicators()
        return out

    def _refresh_indicators(self) -> None:
        """Colour the lamp bulb and the stove indicator from their switch joints (derived, never stored)."""
        light_on = self.joint("light_switch_joint") > 0
        burner_on = self.joint("burner_switch_joint") > 0
        rgba = self.sim.model.geom_rgba
        rgba[self._bulb] = (1.0, 0.95, 0.5, 1.0) if light_on else (0.4, 0.4, 0.35, 1.0)
        rgba[self._indicator] = (1.0, 0.2, 0.1, 1.0) if burner_on else (0.3, 0.05, 0.05, 1.0)

    def reward(self, action=None) -> float:
        return 0.0

    def _check_success(self) -> bool:
        return False
