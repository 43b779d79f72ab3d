"""Policy stage: the `skillret` LeRobot policy (skill VAE + latent policy), its config and processors."""

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig

__all__ = ["SkillRetConfig"]
