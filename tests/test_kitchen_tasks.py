"""Kitchen task definitions, predicates and initial-state sampling (no simulator needed)."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen import predicates as P
from lerobot_skillret.kitchen.primitives import PLACE_REGIONS, PRIMITIVES
from lerobot_skillret.kitchen.sampling import CLEARANCE, sample_poses
from lerobot_skillret.kitchen.tasks import DEFAULT_JOINTS, TASKS, get_task


class FakeScene:
    """Bodies at given positions (identity orientation) and given joint values."""

    def __init__(self, positions: dict[str, tuple[float, float, float]], joints: dict[str, float]):
        self.positions = {k: np.array(v, dtype=float) for k, v in positions.items()}
        self.joints = joints

    def body_pos(self, name):
        return self.positions[name]

    def body_quat(self, name):
        return np.array([1.0, 0.0, 0.0, 0.0])

    def joint(self, name):
        return self.joints[name]


def _breakfast_scene(butter_dy: float) -> FakeScene:
    cx, cy = layout.FIXTURES["serving"]
    return FakeScene(
        {
            "bread": (cx, cy, layout.item_rest_z("bread", layout.TABLE_Z + 0.01)),
            "butter": (cx, cy + butter_dy, layout.item_rest_z("butter", layout.TABLE_Z + 0.004)),
            "milk": (cx, cy - 0.09, layout.item_rest_z("milk", layout.TABLE_Z + 0.004)),
        },
        {},
    )


def test_breakfast_goal_depends_on_side_of_plate():
    task = get_task("breakfast")
    assert task.success(_breakfast_scene(+0.09))
    assert task.unmet(_breakfast_scene(-0.09)) == ["butter_left_of_plate"]


def test_switch_and_drawer_predicates_read_joints():
    scene = FakeScene({}, {"light_switch_joint": 0.02, "burner_switch_joint": -0.02, "drawer_slide": -0.19})
    assert P.switch_on("light")(scene) and P.switch_on("burner", on=False)(scene)
    assert P.drawer_open()(scene) and not P.drawer_closed()(scene)


def test_in_drawer_follows_the_tray():
    tray = (*layout.drawer_tray_xy(-0.2), 0.9)
    scene = FakeScene({"drawer_tray": tray, "block_red": (tray[0], tray[1], layout.DRAWER_FLOOR_Z + 0.02)}, {})
    assert P.in_drawer("block_red")(scene)
    scene.positions["block_red"] = np.array([tray[0] + 0.2, tray[1], layout.TABLE_Z + 0.02])
    assert not P.in_drawer("block_red")(scene)


class FakeEef:
    """Just the gripper: at the origin with a given orientation matrix."""

    def __init__(self, mat: np.ndarray):
        self.mat = mat

    def eef_pos(self):
        return np.zeros(3)

    def eef_mat(self):
        return self.mat

    def gripper_qpos(self):
        return np.zeros(2)


def test_rotation_conventions():
    """Quaternions are (w, x, y, z) with w >= 0, yaw is the heading, and the servo turns the gripper back to DOWN."""
    from scipy.spatial.transform import Rotation

    from lerobot_skillret.kitchen.observations import agent_pos
    from lerobot_skillret.kitchen.primitives import DOWN, ROT_SCALE, Driver

    assert P.yaw(np.array([np.cos(0.35), 0.0, 0.0, np.sin(0.35)])) == pytest.approx(0.7)
    # 0.1 rad about world x off DOWN: scipy's (x, y, z, w) has w < 0 here, so this checks order and sign.
    eef = FakeEef(Rotation.from_rotvec([0.1, 0.0, 0.0]).as_matrix() @ DOWN)
    quat = agent_pos(eef)[3:7]
    assert quat[0] > 0 and np.allclose(Rotation.from_quat(quat, scalar_first=True).as_matrix(), eef.mat, atol=1e-6)
    action = Driver(eef, np.random.default_rng(0)).servo_action(np.zeros(3))
    np.testing.assert_allclose(action[3:6] * ROT_SCALE, [-0.1, 0.0, 0.0], atol=1e-12)


def test_registry_is_consistent():
    assert {"breakfast", "cook", "setup_pan", "setting_up", "cleaning_up"} <= set(TASKS)
    for task in TASKS.values():
        assert task.goals and task.max_steps > 0 and task.description
        assert set(task.init) <= set(layout.MOVABLES)
        for step in task.plan:
            assert step.primitive in PRIMITIVES
            if step.primitive == "pick_place":
                assert step.args[0] in layout.ITEMS and step.args[1] in PLACE_REGIONS
    with pytest.raises(KeyError, match="Unknown kitchen task"):
        get_task("nope")


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"init": {"fsh": ("center",)}}, "unknown objects ['fsh']"),
        ({"init": {"fish": ("frnt_left",)}}, "init['fish'] = ('frnt_left',)"),
        ({"init": {"fish": ("stove", "center")}}, "init['fish']"),
        ({"init": {b: ("shelf",) for b in layout.BLOCKS}}, "3 objects start on the shelf"),
        ({"joints": {**DEFAULT_JOINTS, "drawer_slide": 0.1}}, "joints['drawer_slide'] = 0.1"),
        ({"joints": {"drawer_slide": 0.0}}, "joints must set exactly"),
        ({"plan": ()}, "needs goals, a plan"),
    ],
)
def test_a_malformed_task_is_refused_when_defined_naming_the_field(change, named):
    """A task of your own with a typo fails where it is defined, not as a KeyError inside the sampler."""
    with pytest.raises(ValueError, match=re.escape(named)) as error:
        dataclasses.replace(TASKS["fish_in_pan"], **change)
    assert "'fish_in_pan'" in str(error.value)


@pytest.mark.parametrize("name", sorted(TASKS))
def test_sampling_is_seeded_and_keeps_clearance(name):
    task = TASKS[name]
    poses_a, joints_a = sample_poses(task, np.random.default_rng(3))
    poses_b, _ = sample_poses(task, np.random.default_rng(3))
    assert poses_a == poses_b and set(poses_a) == set(layout.MOVABLES)
    assert joints_a == task.joints
    on_table = [n for n in task.init if task.init[n][0] in layout.REGIONS]
    for i, a in enumerate(on_table):
        for b in on_table[i + 1 :]:
            dist = np.hypot(poses_a[a][0] - poses_a[b][0], poses_a[a][1] - poses_a[b][1])
            assert dist >= layout.spacing_radius(a) + layout.spacing_radius(b) + CLEARANCE - 1e-9
    parked = [n for n in layout.MOVABLES if n not in task.init]
    x0, x1, y0, y1 = layout.WORK_AREA
    assert all(not (x0 < poses_a[n][0] < x1 and y0 < poses_a[n][1] < y1) for n in parked)


def test_the_ladder_has_every_level():
    levels = {task.level for task in TASKS.values()}
    assert {1, 2, 3} <= levels
    assert all(get_task(name).level == 1 for name in ("bread_on_plate", "pan_on_stove", "light_on"))


def test_tasks_from_an_installed_entry_point_reach_every_command(tmp_path):
    """A task declared by another distribution (the examples/custom_task package, as if pip-installed) is in the
    registry, the gym ids, the EnvConfig, the pipeline config and skillret-generate's choices, in a fresh process."""
    example = Path(__file__).resolve().parents[1] / "examples" / "custom_task" / "my_kitchen_tasks.py"
    (tmp_path / "my_kitchen_tasks.py").write_text(example.read_text())
    dist = tmp_path / "my_kitchen_tasks-0.1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: my-kitchen-tasks\nVersion: 0.1.0\n")
    (dist / "entry_points.txt").write_text("[lerobot_skillret.tasks]\nmilk = my_kitchen_tasks:tasks\n")
    code = (
        "import gymnasium as gym; import lerobot_skillret\n"
        "from lerobot_skillret.kitchen.tasks import TASKS\n"
        "from lerobot_skillret.kitchen.env_config import PandaKitchenEnv\n"
        "from lerobot_skillret.pipeline.config import PipelineConfig\n"
        "assert TASKS['milk_right_of_plate'].level == 1\n"
        "assert 'gym_panda_kitchen/milk_right_of_plate' in gym.registry\n"
        "PandaKitchenEnv(task='milk_right_of_plate'); PipelineConfig(tasks=['milk_right_of_plate'])\n"
    )
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    subprocess.run([sys.executable, "-c", code], check=True, env=env)
    generate_help = subprocess.run(
        [str(Path(sys.executable).parent / "skillret-generate"), "demos", "--help"],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    ).stdout
    assert "milk_right_of_plate" in generate_help


def test_play_draws_each_primitive_equally_often_whatever_its_number_of_calls():
    from lerobot_skillret.kitchen.play import draw_step
    from lerobot_skillret.kitchen.tasks import Step

    options = [Step("pick_place", ("bread", f"region{i}")) for i in range(20)] + [Step("toggle", ("light", "on"))]
    rng = np.random.default_rng(0)
    draws = [draw_step(options, rng).primitive for _ in range(2000)]
    assert 0.45 < draws.count("toggle") / len(draws) < 0.55  # uniform over calls would give 1/21


def test_play_draws_plan_steps_at_least_half_the_time_and_counts_them():
    from lerobot_skillret.kitchen.play import PLAN_SHARE, draw_step, plan_coverage, plan_steps
    from lerobot_skillret.kitchen.tasks import Step

    milk_right = Step("pick_place", ("milk", "placemat_right"))  # breakfast's last step
    assert milk_right in plan_steps()
    options = [Step("pick_place", ("milk", f"region{i}")) for i in range(17)] + [milk_right]
    rng = np.random.default_rng(0)
    share = np.mean([draw_step(options, rng, plan_steps()) == milk_right for _ in range(2000)])
    assert 0.4 < PLAN_SHARE < share < PLAN_SHARE + 2 / 18  # uniform arguments alone: 1/18
    coverage = plan_coverage([[("pick_place", "milk", "placemat_right", True), ("toggle", "light", "on", False)]])
    assert coverage["pick_place(milk, placemat_right)"] == 1 and coverage["toggle(light, on)"] == 0
    counts = list(coverage.values())
    assert len(counts) == len(plan_steps()) and counts == sorted(counts)  # fewest first


def test_play_starts_from_every_built_in_task_scene():
    from lerobot_skillret.kitchen.play import play_scene_task
    from lerobot_skillret.kitchen.tasks import LADDER, MULTI_STEP

    rng = np.random.default_rng(0)
    seen = {play_scene_task(rng).name for _ in range(400)}
    in_play = [task for task in (*LADDER, *MULTI_STEP) if task.play_scene]
    assert seen == {task.name for task in in_play}

    # a task kept out of play shares its scene (initial-state distribution) with one in play
    def scene(task):
        return sorted(task.init.items()), sorted(task.joints.items())

    for task in (*LADDER, *MULTI_STEP):
        assert task.play_scene or any(scene(task) == scene(other) for other in in_play), task.name
