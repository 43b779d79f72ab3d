"""The calibration tool's BC references (`benchmarks/kitchen_learnability.py`): the RNN's rollout actor must act as
the network it trained (same hidden state, same horizon), and the windows must stop at an episode's end."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "kitchen_learnability.py"


def _load():
    spec = importlib.util.spec_from_file_location("kitchen_learnability", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_windows_repeat_the_last_frame_of_their_episode():
    kl = _load()
    end = torch.tensor([3, 3, 3, 5, 5])  # two episodes: frames 0-2 and 3-4
    assert kl.ahead(end, 4).tolist() == [[0, 1, 2, 2], [1, 2, 2, 2], [2, 2, 2, 2], [3, 4, 4, 4], [4, 4, 4, 4]]


def test_rnn_actor_replays_the_trained_sequence_and_resets_every_horizon():
    kl = _load()
    torch.manual_seed(0)
    model = kl.RNN(obs_dim=5, action_dim=3, width=16).eval()
    steps = kl.RNN_HORIZON + 4
    obs = torch.randn(steps, 5)
    act = model.actor()
    with torch.no_grad():
        online = np.stack([act(o) for o in obs])
        first = model(obs[None, : kl.RNN_HORIZON])[0].numpy()  # what training saw: a sequence from a zero state
        second = model(obs[None, kl.RNN_HORIZON :])[0].numpy()  # the next horizon starts from zero again
    np.testing.assert_allclose(online[: kl.RNN_HORIZON], first, atol=1e-6)
    np.testing.assert_allclose(online[kl.RNN_HORIZON :], second, atol=1e-6)


def test_mlp_actor_runs_the_first_actions_of_each_chunk():
    kl = _load()
    torch.manual_seed(0)
    model = kl.MLP(obs_dim=5, action_dim=3, width=16).eval()
    obs = torch.randn(2 * kl.EXECUTE, 5)
    act = model.actor()
    with torch.no_grad():
        online = np.stack([act(o) for o in obs])
        planned = [model(obs[i][None])[0, : kl.EXECUTE].numpy() for i in (0, kl.EXECUTE)]
    np.testing.assert_allclose(online, np.concatenate(planned), atol=1e-6)


def test_table_rebuilds_the_stored_results_markdown(tmp_path: Path):
    """`--table` (no training) rewrites results.md from the stored task results, as its help says, and marks the
    rows rolled out with the continuous gripper command (results from before 2026-12-05 lack the key)."""
    published = json.loads((SCRIPT.parent / "results" / "learnability" / "bc_rnn" / "light_on.json").read_text())
    continuous = {key: value for key, value in published.items() if key != "discrete_gripper"}
    (tmp_path / "light_on.json").write_text(json.dumps({**continuous, "task": "light_on"}))
    (tmp_path / "open_drawer.json").write_text(
        json.dumps({**published, "task": "open_drawer", "discrete_gripper": True})
    )
    (tmp_path / "results.md").write_text("stale\n")
    subprocess.run(
        [sys.executable, str(SCRIPT), "--reference", "rnn", "--table", "--results", str(tmp_path)],
        check=True,
        capture_output=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )
    markdown = (tmp_path / "results.md").read_text()
    assert "stale" not in markdown
    rows = {line.split(" | ")[1]: line for line in markdown.splitlines() if line.startswith("| 1 |")}
    assert " | 50‡ | " in rows["light_on"] and " | 50 | " in rows["open_drawer"]


def test_a_stored_result_is_reused_only_for_the_same_seeds_and_gripper_command():
    """A re-run skips a task only when its stored result answers the same question: the published results from
    before the discrete gripper became the env's default lack the key and ran the continuous command."""
    kl = _load()
    stored = json.loads((SCRIPT.parent / "results" / "learnability" / "bc_rnn" / "light_on.json").read_text())
    published = {key: value for key, value in stored.items() if key != "discrete_gripper"}  # as before 2026-12-05
    assert kl.redo_reason(published, discrete_gripper=False) is None
    assert "discrete_gripper=False" in kl.redo_reason(published, discrete_gripper=True)
    assert kl.redo_reason({**published, "discrete_gripper": True}, discrete_gripper=True) is None
    elsewhere = {**published, "eval_seeds": [100_000], "discrete_gripper": True}
    assert "100000+" in kl.redo_reason(elsewhere, discrete_gripper=True)


def test_act_reference_uses_the_benchmark_settings_and_masks_padding():
    """LeRobot's ACT as the reference: the benchmark's `act` network (chunk from benchmark.yaml), the state split off
    the front of the observation, and chunk steps past an episode's end marked as padding, as LeRobot's loader does."""
    kl = _load()
    model = kl.ACT(obs_dim=12, action_dim=3)
    chunk = model.policy.config.chunk_size
    assert chunk == kl.act_settings()["chunk_size"] == 20
    end = torch.tensor([3, 3, 3, 25, 25] + [25] * 20)  # episodes: frames 0-2 and 3-24
    obs, action = torch.randn(len(end), 12), torch.randn(len(end), 3)
    batch = model.examples(obs, action, end)
    assert batch["observation.state"].shape == (len(end), len(kl.STATE_NAMES))
    assert batch["observation.environment_state"].shape == (len(end), 12 - len(kl.STATE_NAMES))
    assert batch["action_is_pad"][0].tolist() == [False] * 3 + [True] * (chunk - 3)
    assert batch["action_is_pad"][3].tolist() == [False] * chunk  # 22 frames left: a full chunk
    assert batch["action_is_pad"][5].tolist() == [False] * 20  # frames 5-24
    torch.testing.assert_close(batch["action"][1, :2], action[1:3])


def test_every_reference_trains_through_the_shared_loop():
    """One loop for MLP, BC-RNN and ACT: a few epochs on a tiny episode lower each one's loss."""
    kl = _load()
    torch.manual_seed(0)
    end = torch.tensor([40] * 40 + [80] * 40)
    obs = torch.randn(80, 12)
    action = torch.tanh(obs[:, :3] + obs[:, 9:12])  # learnable from the current observation
    for name, model in (("mlp", kl.MLP(12, 3, width=32)), ("rnn", kl.RNN(12, 3, width=32)), ("act", kl.ACT(12, 3))):
        _, training = kl.train(model, obs, action, end, 30, 16, kl.DEFAULT_LR[name] * 3, float("inf"), "cpu")
        curve = training["loss_curve"]
        assert curve[-1] < 0.8 * curve[0], (name, curve[0], curve[-1])
