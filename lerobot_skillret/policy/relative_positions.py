"""Object positions relative to the gripper (`SkillRetConfig.relative_positions`; not in the paper).

With absolute positions a skill latent learns where its own demonstration's motion went; given relative to the end
effector, "the bread is 10 cm ahead of the gripper" reads the same in every scene, so the decoder and the latent
policy can reuse one skill wherever the objects are. The end effector is `observation.state[:3]`; each chosen
(x, y, z) triple of `observation.environment_state` becomes object minus end effector before normalisation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE
from torch import Tensor

EEF = slice(0, 3)  # the end-effector position in `observation.state`
MOMENTS = ("mean", "std", "min", "max")  # the statistics the skill normaliser reads (quantiles stay absolute)


def to_relative(observation: Mapping[str, Tensor], starts: Sequence[int]) -> dict[str, Tensor]:
    """A copy of `observation` (RAW tensors (..., D)) whose environment-state triples at `starts` are object minus
    end effector."""
    if not starts:
        return dict(observation)
    env = observation[OBS_ENV_STATE].clone()
    eef = observation[OBS_STATE][..., EEF]
    for start in starts:
        env[..., start : start + 3] -= eef
    return {**observation, OBS_ENV_STATE: env}


def relative_stats(stats: Mapping[str, Mapping[str, object]], starts: Sequence[int]) -> dict:
    """Dataset statistics with those of the relative triples in place of the absolute ones.

    Derived from the two features' own statistics: the mean of a difference is exact, min_o - max_e and
    max_o - min_e bound it, and the std is sqrt(std_o^2 + std_e^2) as if object and gripper moved independently.
    The normaliser needs a scale of the right order, and lerobot-train hands the policy these statistics, not data."""
    if not starts:
        return dict(stats)
    env = {k: np.array(v, dtype=np.float64).reshape(-1) for k, v in stats[OBS_ENV_STATE].items() if k in MOMENTS}
    eef = {k: np.asarray(v, dtype=np.float64).reshape(-1)[EEF] for k, v in stats[OBS_STATE].items() if k in MOMENTS}
    for start in starts:
        rows = slice(start, start + 3)
        if "mean" in env:
            env["mean"][rows] -= eef["mean"]
        if "std" in env:
            env["std"][rows] = np.sqrt(env["std"][rows] ** 2 + eef["std"] ** 2)
        if "min" in env:
            env["min"][rows], env["max"][rows] = env["min"][rows] - eef["max"], env["max"][rows] - eef["min"]
    return {**stats, OBS_ENV_STATE: {**stats[OBS_ENV_STATE], **env}}
