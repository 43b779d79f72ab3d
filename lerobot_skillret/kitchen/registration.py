"""Registers `gym_panda_kitchen/<task>` gym ids with string entry points (no robosuite import at registration)."""

from __future__ import annotations

import gymnasium as gym

from lerobot_skillret.kitchen.tasks import TASKS

ENV_NAMESPACE = "gym_panda_kitchen"
ENTRY_POINT = "lerobot_skillret.kitchen.gym_env:KitchenEnv"


def gym_id(task: str) -> str:
    return f"{ENV_NAMESPACE}/{task}"


def register_envs() -> None:
    """Idempotent: registers one gym id per task in `tasks.TASKS`."""
    for name in TASKS:
        if gym_id(name) in gym.registry:
            continue
        gym.register(
            id=gym_id(name),
            entry_point=ENTRY_POINT,
            kwargs={"task": name},
            max_episode_steps=None,
            order_enforce=False,
            disable_env_checker=True,
        )
