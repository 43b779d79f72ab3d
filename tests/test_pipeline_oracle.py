"""The oracle's phase alignment picks the demonstration frame nearest the robot, only inside its search window."""

from __future__ import annotations

from types import SimpleNamespace

import torch

from lerobot_skillret.pipeline.oracle import _closest_frame


def test_closest_frame_is_the_nearest_observation_in_the_window() -> None:
    state = torch.arange(40, dtype=torch.float32)[:, None].repeat(1, 3)  # frame i observes (i, i, i)
    env = torch.zeros(40, 2)
    columns = SimpleNamespace(td={"observation.state": state, "observation.environment_state": env})
    identity = SimpleNamespace(normalize=lambda key, value: value)
    policy = SimpleNamespace(low_dim_keys=["observation.environment_state", "observation.state"], normalizer=identity)
    sampler = SimpleNamespace(columns=columns)

    def now(value: float) -> dict:
        return {"observation.state": torch.full((1, 3), value), "observation.environment_state": torch.zeros(1, 2)}

    # demonstration starting at global frame 10: step k observes 10 + k
    assert _closest_frame(policy, sampler, now(17.2), first=10, lo=0, hi=20) == 7
    assert _closest_frame(policy, sampler, now(17.2), first=10, lo=9, hi=20) == 9  # never behind the window
    assert _closest_frame(policy, sampler, now(99.0), first=10, lo=0, hi=5) == 5  # never past it
