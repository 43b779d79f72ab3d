"""The oracle harness: phase alignment inside its search window; which skills the latent policy chooses."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from lerobot_skillret.pipeline.oracle import _closest_frame, oracle_episode


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


def test_policy_every_leaves_every_nth_skill_to_the_latent_policy() -> None:
    """0: every skill is the oracle's; n: the n-th, 2n-th, ... skills are the policy's own (`select_action`)."""

    class Env:
        def reset(self, options):
            return {"agent_pos": np.zeros(3, dtype=np.float32)}, {}

        def step(self, action):
            return {"agent_pos": np.zeros(3, dtype=np.float32)}, 0.0, False, False, {"is_success": False}

        def unmet_goals(self):
            return ["goal"]

    oracle_starts: list[int] = []
    policy = SimpleNamespace(
        config=SimpleNamespace(horizon=2),
        reset=lambda: None,
        encode_skill=lambda window: (window, None),
        execute_skill=lambda anchor: oracle_starts.append(int(anchor[0])),
        select_action=lambda batch: torch.zeros(1, 7),
    )
    sampler = SimpleNamespace(gather=lambda anchor: anchor)
    for every, expected in [(0, [0, 2, 4, 6, 8]), (2, [0, 4, 8]), (3, [0, 2, 6, 8]), (1, [])]:
        oracle_starts.clear()
        oracle_episode(policy, Env(), sampler, 0, 10, np.zeros(1), slack=1.0, policy_every=every)
        assert oracle_starts == expected, every
