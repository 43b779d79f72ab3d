"""LeRobot EnvConfig `panda_kitchen`: lets `lerobot-eval --env.type=panda_kitchen --env.task=<task>` run.

Features are derived from `observations` (the one observation layout). Importing this module also registers
the `gym_panda_kitchen/<task>` gym ids (string entry points), so importing it is all `lerobot-eval` needs.
Import-light: no robosuite here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.layout import CONTROL_FREQ
from lerobot_skillret.kitchen.registration import register_envs

register_envs()


@EnvConfig.register_subclass("panda_kitchen")
@dataclass
class PandaKitchenEnv(EnvConfig):
    task: str | None = "breakfast"
    fps: int = CONTROL_FREQ
    episode_length: int | None = None  # None: the task's own max_steps
    cameras: tuple[str, ...] = ()
    image_size: int = O.DEFAULT_IMAGE_SIZE
    # lerobot-eval renders every step of its first 10 episodes; a stride k re-renders every k steps (videos at fps/k)
    render_stride: int = 1
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        self.cameras = O.check_cameras(self.cameras)
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
            "cameras": tuple(self.cameras),
            "image_size": self.image_size,
            "episode_length": self.episode_length,
            "render_stride": self.render_stride,
        }
