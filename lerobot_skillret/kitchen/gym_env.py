"""Gymnasium env for one kitchen task (`gym_panda_kitchen/<task>`), as LeRobot's eval expects it.

Observations come from `observations.build_observation`; success from the task's predicates; the episode
terminates on success and is truncated at the task's `max_steps`. The reward is the fraction of the goals unmet at
reset that are met now (1.0 on success), so a failed rollout still reports how far it got; `info["in_a_row"]` is how
many of them hold in the plan's order up to the first that does not (CALVIN's chain length). The
gripper command is rounded to the expert's three (open / hold / close) unless `discrete_gripper=False`.
"""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.expert import reset_scene
from lerobot_skillret.kitchen.layout import CONTROL_FREQ
from lerobot_skillret.kitchen.registration import check_env_options
from lerobot_skillret.kitchen.rendering import CameraRenderer
from lerobot_skillret.kitchen.scene import KitchenScene
from lerobot_skillret.kitchen.tasks import get_task

RENDER_SIZE = 256
GRIPPER = O.ACTION_NAMES.index("gripper")  # the command the fingers integrate (`discrete_gripper` rounds it)


class KitchenEnv(gym.Env):
    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": CONTROL_FREQ}

    def __init__(
        self,
        task: str = "breakfast",
        cameras: tuple[str, ...] | list[str] = (),
        image_size: int = O.DEFAULT_IMAGE_SIZE,
        episode_length: int | None = None,
        render_mode: str = "rgb_array",
        render_stride: int = 1,
        discrete_gripper: bool = True,
    ):
        self.cameras = check_env_options(cameras, image_size, episode_length, render_stride)
        self._task = get_task(task)
        self.task = task
        self.task_description = self._task.description
        self.image_size = image_size
        self.render_mode = render_mode
        self.render_stride = render_stride
        self.discrete_gripper = discrete_gripper
        self._frame: np.ndarray | None = None
        self._max_episode_steps = self._task.max_steps if episode_length is None else int(episode_length)
        self.scene = KitchenScene()
        self._cam = CameraRenderer(self.scene, image_size) if self.cameras else None
        self._viewer: CameraRenderer | None = None
        obs_spaces = {
            "agent_pos": spaces.Box(-np.inf, np.inf, (len(O.STATE_NAMES),), np.float32),
            "environment_state": spaces.Box(-np.inf, np.inf, (len(O.ENV_STATE_NAMES),), np.float32),
        }
        if self.cameras:
            obs_spaces["pixels"] = spaces.Dict(
                {c: spaces.Box(0, 255, (image_size, image_size, 3), np.uint8) for c in self.cameras}
            )
        self.observation_space = spaces.Dict(obs_spaces)
        self.action_space = spaces.Box(-1.0, 1.0, (len(O.ACTION_NAMES),), np.float32)
        self._steps = 0
        self._met_at_reset: tuple[bool, ...] = ()

    def _obs(self) -> dict:
        return O.build_observation(self.scene, self._cam, self.cameras)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """`options={"initial_state": state}` restores a recorded episode's initial MuJoCo state (the
        `initial_state` a generated dataset stores in meta/kitchen.json) instead of sampling one."""
        super().reset(seed=seed)
        if options and options.get("initial_state") is not None:
            self.scene.reset()
            self.scene.set_sim_state(np.asarray(options["initial_state"], dtype=np.float64))
        else:
            reset_scene(self.scene, self._task, self.np_random)
        self._steps = 0
        self._frame = None
        self._met_at_reset = self._task.goals_met(self.scene)
        return self._obs(), {"is_success": False}

    def step(self, action):
        action = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        if self.discrete_gripper:
            action[GRIPPER] = np.round(action[GRIPPER])
        self.scene.step(action)
        self._steps += 1
        success = self._task.success(self.scene)
        reward = 1.0 if success else self._task.progress(self.scene, self._met_at_reset)
        truncated = self._steps >= self._max_episode_steps and not success
        info = {"is_success": success, "in_a_row": self._task.in_a_row(self.scene, self._met_at_reset)}
        return self._obs(), reward, success, truncated, info

    def unmet_goals(self) -> list[str]:
        """Names of the task's sub-goals that do not hold now (diagnostics: where a rollout stopped)."""
        return self._task.unmet(self.scene)

    def render(self):
        """Video frame; with `render_stride` k a fresh frame every k steps (rendering costs ~5x a sim step)."""
        if self._frame is None or self._steps % self.render_stride == 0:
            if self._viewer is None:
                self._viewer = CameraRenderer(self.scene, RENDER_SIZE)
            self._frame = self._viewer.render("agentview")
        return self._frame

    def close(self):
        for r in (self._cam, self._viewer):
            if r is not None:
                r.close()
        self._cam = self._viewer = None
