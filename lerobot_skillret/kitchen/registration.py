"""Registers `gym_panda_kitchen/<task>` gym ids with string entry points (no robosuite import at registration), and
checks the options both `gym.make` and `lerobot-eval --env.*` pass to the env."""

from __future__ import annotations

import gymnasium as gym

from lerobot_skillret.kitchen import observations as O
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


def check_env_options(
    cameras: object, image_size: int, episode_length: int | None, render_stride: int
) -> tuple[str, ...]:
    """Refuse option values the env would run with silently wrong (an episode_length of 0 used to mean the task's
    own, -3 one step; a 0-pixel image); returns the cameras as a tuple. Each message starts with the option's name."""
    if episode_length is not None and episode_length < 1:
        raise ValueError(f"episode_length must be >= 1, or None (null) for the task's own; got {episode_length}")
    if image_size < 1:
        raise ValueError(f"image_size must be >= 1 pixel (the datasets' is {O.DEFAULT_IMAGE_SIZE}); got {image_size}")
    if render_stride < 1:
        raise ValueError(f"render_stride must be >= 1; got {render_stride}")
    try:
        return O.check_cameras(cameras)
    except ValueError as error:
        raise ValueError(f"cameras: {error}") from None
