"""Tests that pin the method's core against references: each fails on a small, plausible bug that leaves every
shape and loss finite (the bug each guards is named in its docstring; each was checked to fail on it)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from policy_fixtures import PRIOR_REPO, TARGET_REPO, build_policy, tiny_config, training_batch
from synthetic import make_synthetic_dataset

from lerobot_skillret.data.windows import EpisodeColumns
from lerobot_skillret.pipeline.heldout import skill_starts
from lerobot_skillret.policy.latent_policy import TARGET_ID
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy
from lerobot_skillret.policy.skills import gaussian_kl

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def prior_root(tmp_path_factory) -> Path:
    return make_synthetic_dataset(tmp_path_factory.mktemp("prior") / "ds", PRIOR_REPO, num_episodes=4, seed=0)


@pytest.fixture(scope="module")
def target_root(tmp_path_factory) -> Path:
    return make_synthetic_dataset(tmp_path_factory.mktemp("target") / "ds", TARGET_REPO, num_episodes=3, seed=1)


def _observation(batch: dict, policy: SkillRetPolicy, step: int) -> dict:
    return {key: batch[key][:, step] for key in policy.observation_keys}


def test_gaussian_kl_equals_the_closed_form():
    """Reference: the textbook KL of diagonal Gaussians, written out (guards swapped arguments, a sign or a
    variance-for-std slip)."""
    generator = torch.Generator().manual_seed(0)
    mean_q, mean_p = torch.randn(5, 8, generator=generator), torch.randn(5, 8, generator=generator)
    log_var_q, log_var_p = torch.randn(5, 8, generator=generator), torch.randn(5, 8, generator=generator)
    var_q, var_p = log_var_q.exp(), log_var_p.exp()
    reference = 0.5 * (log_var_p - log_var_q + (var_q + (mean_q - mean_p) ** 2) / var_p - 1).sum(-1)
    torch.testing.assert_close(gaussian_kl(mean_q, log_var_q, mean_p, log_var_p), reference)


def test_stage2_target_labels_are_the_target_windows_latents(prior_root, target_root, tmp_path):
    """L_policy on target data regresses the target windows' own encoder means (guards labels taken from the
    prior windows that share the skill model's fine-tuning batch, e.g. `means[-size:]` for `means[:size]`)."""
    torch.manual_seed(0)
    build_policy(tiny_config(), PRIOR_REPO, prior_root).save_pretrained(tmp_path / "stage1")
    config = tiny_config(stage="policy", use_retrieval=False, prior_repo_id=PRIOR_REPO, prior_root=str(prior_root))
    meta = LeRobotDatasetMetadata(TARGET_REPO, root=target_root)
    stage1 = SkillRetPolicy.from_pretrained(tmp_path / "stage1")
    config.input_features, config.output_features = stage1.config.input_features, stage1.config.output_features
    policy = SkillRetPolicy.from_pretrained(
        tmp_path / "stage1", config=config, dataset_stats=meta.stats, dataset_meta=meta
    )
    batch = training_batch(config, TARGET_REPO, target_root, size=6)
    _, info = policy.forward(batch)
    assert "reconstruction_loss" in info  # the prior windows were in the same skill batch
    with torch.no_grad():
        labels, _ = policy.skills.encoder(policy._window(batch))
        predicted = policy.latent_policy(policy._history(batch), torch.full((6,), TARGET_ID))
    expected = float((predicted - labels).pow(2).sum(-1).mean())
    assert info["policy_target_loss"] == pytest.approx(expected, rel=1e-5)
    # the skills' reconstruction and KL on the target windows alone, besides the joint ones over target + prior windows
    window = policy._window(batch)
    with torch.no_grad():
        squared, valid = policy.skills.action_error(labels, window)
        target_kl = gaussian_kl(*policy.skills.encoder(window), *policy.skills.prior(window)).mean()
    target_reconstruction = float((squared * valid).sum() / valid.sum())
    assert info["target_reconstruction_loss"] == pytest.approx(target_reconstruction, rel=1e-5)
    assert info["reconstruction_loss"] != pytest.approx(target_reconstruction, rel=1e-3)
    assert info["target_kl_loss"] == pytest.approx(float(target_kl), rel=1e-5)
    assert info["kl_loss"] != pytest.approx(float(target_kl), rel=1e-3)


def test_history_is_prefilled_with_the_first_observation(prior_root):
    """After `reset`, the first skill is chosen from F copies of the first observation, as LeRobot pads training
    windows at an episode's start (guards an empty or zero-filled history)."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root, size=2)
    first = _observation(batch, policy, 0)
    policy.reset()
    policy.select_action(first)
    frame = policy._observations(first, ...)
    history = {key: value[:, None].expand(-1, config.history, *value.shape[1:]) for key, value in frame.items()}
    with torch.no_grad():
        expected = policy.latent_policy(history, torch.full((2,), TARGET_ID))
    torch.testing.assert_close(policy._skill, expected)


def test_decoder_state_restarts_with_each_new_skill(prior_root):
    """Every H steps the new skill is decoded from a fresh LSTM state, as in training, where each window starts
    from zeros (guards the previous skill's state carried into the next)."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root, size=2)
    policy.reset()
    for step in range(config.horizon):
        policy.select_action(_observation(batch, policy, step % batch["observation.state"].shape[1]))
    observation = {key: value + 0.1 for key, value in _observation(batch, policy, 0).items()}
    action = policy.select_action(observation)  # step H: a new skill
    with torch.no_grad():
        fresh, _ = policy.skills.decoder.step(policy._skill, policy._observations(observation, ...), None)
    torch.testing.assert_close(action, policy.normalizer.unnormalize("action", fresh))


def test_heldout_scoring_points_are_every_h_steps_from_each_episode_start(prior_root):
    """Guards scoring points shifted off the steps where a rollout picks a skill."""
    columns = EpisodeColumns.from_dataset(PRIOR_REPO, prior_root)
    start = columns.td["episode_start"].as_subclass(torch.Tensor)
    end = columns.td["episode_end"].as_subclass(torch.Tensor)
    expected = [
        index
        for first in sorted(set(start.tolist()))
        for index in range(first, int(end[first]), 4)  # H = 4, from each episode's first frame
    ]
    assert skill_starts(columns, 4).tolist() == expected
