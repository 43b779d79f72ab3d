"""The oracle harness: phase alignment inside its search window; which skills the latent policy chooses; which
demonstration each rollout starts from and whose latents it executes; what the per-skill trace reports."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from lerobot_skillret.pipeline import oracle
from lerobot_skillret.pipeline.oracle import _closest_frame, oracle_episode


class Env:
    """A kitchen env that never succeeds; records the initial state of every reset."""

    def __init__(self) -> None:
        self.resets: list[float] = []

    def reset(self, options):
        self.resets.append(float(options["initial_state"][0]))
        return {"agent_pos": np.zeros(3, dtype=np.float32)}, {}

    def step(self, action):
        return {"agent_pos": np.zeros(3, dtype=np.float32)}, 0.0, False, False, {"is_success": False}

    def unmet_goals(self):
        return ["goal"]

    def close(self):
        pass


def test_closest_frame_is_the_nearest_observation_in_the_window() -> None:
    state = torch.arange(40, dtype=torch.float32)[:, None].repeat(1, 3)  # frame i observes (i, i, i)
    env = torch.zeros(40, 2)
    columns = SimpleNamespace(td={"observation.state": state, "observation.environment_state": env})
    keys = ["observation.environment_state", "observation.state"]
    policy = SimpleNamespace(low_dim_keys=keys, low_dim_features=lambda raw: torch.cat([raw[k] for k in keys], -1))
    sampler = SimpleNamespace(columns=columns)

    def now(value: float) -> dict:
        return {"observation.state": torch.full((1, 3), value), "observation.environment_state": torch.zeros(1, 2)}

    # demonstration starting at global frame 10: step k observes 10 + k
    assert _closest_frame(policy, sampler, now(17.2), first=10, lo=0, hi=20) == 7
    assert _closest_frame(policy, sampler, now(17.2), first=10, lo=9, hi=20) == 9  # never behind the window
    assert _closest_frame(policy, sampler, now(99.0), first=10, lo=0, hi=5) == 5  # never past it


def test_policy_every_leaves_every_nth_skill_to_the_latent_policy() -> None:
    """0: every skill is the oracle's; n: the n-th, 2n-th, ... skills are the policy's own (`select_action`)."""
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


def test_swap_starts_from_each_demo_and_executes_the_next_ones_latents(monkeypatch) -> None:
    """Rollout i resets to demo i's initial state and encodes demo i + swap's frames (wrapping around)."""
    firsts, length = [0, 10, 20], 10  # three demos of 10 frames, global frames 0-29
    columns = SimpleNamespace(
        td={"episode_index": torch.arange(30) // length, "episode_end": (torch.arange(30) // length + 1) * length}
    )
    meta = {"episodes": [{"episode_index": e, "initial_state": [float(e)]} for e in range(3)]}
    env, encoded = Env(), []
    policy = SimpleNamespace(
        config=SimpleNamespace(horizon=5, history=1, stage="skills"),
        eval=lambda: policy,
        reset=lambda: None,
        encode_skill=lambda anchors: (anchors, None),
        execute_skill=lambda anchors: encoded.append(int(anchors[0])),
        select_action=lambda batch: torch.zeros(1, 7),
        imitation_error=lambda window: {
            "oracle": torch.zeros(1),
            "shuffled": torch.ones(1),
            "mean_action": torch.ones(1),
        },
    )
    monkeypatch.setattr(oracle, "resolve_checkpoint", lambda checkpoint, *args, **kwargs: checkpoint)
    monkeypatch.setattr(oracle.SkillRetPolicy, "from_pretrained", lambda checkpoint: policy)
    monkeypatch.setattr(oracle.EpisodeColumns, "from_dataset", lambda repo_id, root: columns)
    monkeypatch.setattr(oracle, "WindowSampler", lambda columns, history, horizon: SimpleNamespace(gather=lambda a: a))
    monkeypatch.setattr(oracle, "skill_starts", lambda columns, horizon: torch.tensor(firsts))
    monkeypatch.setattr(oracle, "load_kitchen_meta", lambda root: meta)
    made = []
    monkeypatch.setattr(oracle, "KitchenEnv", lambda task, discrete_gripper: made.append(discrete_gripper) or env)
    monkeypatch.setattr(oracle, "get_task", lambda task: SimpleNamespace(goals=["goal"]))

    for swap, sources in [(0, [0, 1, 2]), (1, [1, 2, 0]), (2, [2, 0, 1])]:
        env.resets.clear(), encoded.clear()
        oracle.oracle_success(oracle.Path("x"), oracle.Path("demos"), "task", slack=1.0, swap=swap, log=lambda *a: None)
        assert env.resets == [0.0, 1.0, 2.0], swap
        assert encoded == [firsts[s] + t for s in sources for t in (0, 5)], swap
    oracle.oracle_success(oracle.Path("x"), oracle.Path("demos"), "task", discrete_gripper=False, log=lambda *a: None)
    assert made == [True, True, True, False]  # the env gets the gripper option (rounded by default)


def test_bad_checkpoints_and_tasks_are_named_before_anything_loads(tmp_path, monkeypatch) -> None:
    """examples/oracle_skills.py ended in LeRobot's HFValidationError ("Repo id must use alphanumeric chars") for a
    mistyped --checkpoint, or "config.json not found" for a run's checkpoint/last folder."""
    monkeypatch.setattr(oracle.SkillRetPolicy, "from_pretrained", lambda *a: pytest.fail("loaded the model"))
    with pytest.raises(FileNotFoundError, match=r"Checkpoint .*nowhere does not exist\. Pass a skillret"):
        oracle.oracle_success(tmp_path / "nowhere", tmp_path, "setup_pan")
    run = tmp_path / "run"
    (run / "checkpoints" / "last" / "pretrained_model").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match=r"is a training run's folder: pass its checkpoint"):
        oracle.oracle_success(run, tmp_path, "setup_pan")
    monkeypatch.setattr(oracle, "resolve_checkpoint", lambda checkpoint, *args, **kwargs: checkpoint)
    with pytest.raises(KeyError, match="Unknown kitchen task 'setup_pann'"):
        oracle.oracle_success(run, tmp_path, "setup_pann")


def test_trace_reports_the_nearest_demo_step_and_goals_met_at_every_skill() -> None:
    """The robot's state walks 0, 1, 2, ... while the demonstration's frame k observes 1.5 k: at step t the nearest
    demonstration step is t / 1.5; the one goal is met from step 5 on."""
    demo = torch.arange(10, dtype=torch.float32)[:, None].repeat(1, 3) * 1.5
    columns = SimpleNamespace(td={"observation.state": demo})

    class WalkingEnv(Env):
        def reset(self, options):
            self.t = 0
            return {"agent_pos": np.zeros(3, dtype=np.float32)}, {}

        def step(self, action):
            self.t += 1
            return {"agent_pos": np.full(3, self.t, dtype=np.float32)}, 0.0, False, False, {"is_success": False}

        def unmet_goals(self):
            return [] if self.t >= 5 else ["goal"]

    policy = SimpleNamespace(
        config=SimpleNamespace(horizon=3),
        reset=lambda: None,
        low_dim_keys=["observation.state"],
        low_dim_features=lambda raw: raw["observation.state"],
        select_action=lambda batch: torch.zeros(1, 7),
    )
    sampler = SimpleNamespace(columns=columns)
    trace: list[tuple[int, int]] = []
    oracle_episode(policy, WalkingEnv(), sampler, 0, 10, np.zeros(1), slack=1.2, policy_every=1, trace=trace)
    assert trace == [(0, 0), (2, 0), (4, 1), (6, 1)]  # skills start at t = 0, 3, 6, 9 (12 steps)
