"""lerobot-skillret: skill-based imitation with retrieval from prior play data, as a LeRobot plugin.

Importing this package registers the `skillret` policy type and the `panda_kitchen` env type with LeRobot, and the
kitchen gym ids `gym_panda_kitchen/<task>` (string entry points). It stays light: robosuite and mujoco are only
imported when an env is made or data is generated.

Pipeline, in reading order: kitchen (data generation) -> data (windows) -> policy (skills, latent policy)
-> retrieval -> pipeline (end-to-end runs, evaluation, results).
"""

from importlib.metadata import version

from lerobot_skillret.kitchen.env_config import PandaKitchenEnv  # registers the gym ids too
from lerobot_skillret.policy.configuration_skillret import SkillRetConfig

__all__ = ["PandaKitchenEnv", "SkillRetConfig"]
__version__ = version("lerobot_policy_skillret")
