"""LeRobot EnvConfig `panda_kitchen`: lets `lerobot-eval --env.type=panda_kitchen --env.task=<task>` run.

Features are derived from `observations` (the one observation layout). The envs are built by LeRobot 0.6's
`EnvConfig.create_envs()` hook, so LeRobot's own `make_env_config("panda_kitchen", ...)` / `make_env(cfg)` path
builds them; the env processors are LeRobot's default identity pipelines, because the kitchen already emits the
`agent_pos` / `environment_state` / `pixels` layout LeRobot's `preprocess_observation` expects. Importing this module
also registers the `gym_panda_kitchen/<task>` gym ids (string entry points), for `gym.make` users.
Import-light: no robosuite here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.layout import CONTROL_FREQ
from lerobot_skillret.kitchen.registration import check_env_options, register_envs
from lerobot_skillret.kitchen.tasks import TASKS

register_envs()


@EnvConfig.register_subclass("panda_kitchen")
@dataclass
class PandaKitchenEnv(EnvConfig):
    task: str | None = "breakfast"  # one of the kitchen's tasks (`lerobot_skillret.kitchen.tasks.TASKS`)
    fps: int = CONTROL_FREQ
    episode_length: int | None = None  # None: the task's own max_steps
    cameras: tuple[str, ...] = ()
    image_size: int = O.DEFAULT_IMAGE_SIZE
    # lerobot-eval renders every step of its first 10 episodes; a stride k re-renders every k steps (videos at fps/k)
    render_stride: int = 1
    # round the gripper command to -1 / 0 / +1 (open / hold / close), the only three the expert and the play data
    # send: unrounded, a learner's small non-zero "hold" integrates in the gripper and closes the fingers again on an
    # object it has just released (`KitchenEnv`). `false` reproduces the tables published before 2026-12-05
    discrete_gripper: bool = True
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        if self.task not in TASKS:
            raise ValueError(f"Unknown panda_kitchen task {self.task!r}. Pass --env.task=<one of {sorted(TASKS)}>.")
        if self.fps != CONTROL_FREQ:  # lerobot-eval would only label its videos with it
            raise ValueError(f"--env.fps is fixed: the kitchen runs at {CONTROL_FREQ} Hz; got {self.fps}")
        try:
            self.cameras = check_env_options(self.cameras, self.image_size, self.episode_length, self.render_stride)
        except ValueError as error:
            raise ValueError(f"--env.{error}") from None
        self.features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(len(O.ACTION_NAMES),))}
        self.features_map = {"action": "action", **O.ENV_TO_DATASET}
        types = {"agent_pos": FeatureType.STATE, "environment_state": FeatureType.ENV}
        for key, shape in O.env_feature_shapes(self.cameras, self.image_size).items():
            feature_type = FeatureType.VISUAL if key.startswith("pixels/") else types[key]
            self.features[key] = PolicyFeature(type=feature_type, shape=shape)
            if key.startswith("pixels/"):
                self.features_map[key] = O.image_key(key.split("/", 1)[1])

    @property
    def gym_kwargs(self) -> dict:
        return {
            "task": self.task,
            "cameras": tuple(self.cameras),
            "image_size": self.image_size,
            "episode_length": self.episode_length,
            "render_stride": self.render_stride,
            "discrete_gripper": self.discrete_gripper,
        }

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        """`{"panda_kitchen": {0: VectorEnv of n_envs kitchens}}`, LeRobot's single-task layout.

        Async envs run each kitchen in its own process (forkserver, as LeRobot does); each builds its own MuJoCo
        scene, so there is nothing to share."""
        kwargs = self.gym_kwargs
        factories = [lambda: make_kitchen_env(**kwargs) for _ in range(n_envs)]
        if use_async_envs and n_envs > 1:
            vector = gym.vector.AsyncVectorEnv(
                factories, context="forkserver", autoreset_mode=gym.vector.AutoresetMode.SAME_STEP
            )
        else:
            vector = gym.vector.SyncVectorEnv(factories, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
        return {self.type: {0: vector}}


def make_kitchen_env(**kwargs: object) -> gym.Env:
    """One kitchen env (imports robosuite/mujoco on first call, in whichever process builds it)."""
    from lerobot_skillret.kitchen.gym_env import KitchenEnv

    return KitchenEnv(**kwargs)
