"""Checkpoints: save/load gives bit-identical actions; push_to_hub uploads weights, configs, processors and a card
naming the method and the datasets (hub calls mocked: no network)."""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from huggingface_hub import HfApi, RepoCard
from lerobot.configs.default import DatasetConfig
from lerobot.configs.train import TrainPipelineConfig
from policy_fixtures import PRIOR_REPO, TARGET_REPO, build_policy, tiny_config, training_batch
from synthetic import make_synthetic_dataset

from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy
from lerobot_skillret.policy.processor_skillret import make_skillret_pre_post_processors

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> SkillRetPolicy:
    """A stage-2 policy after a few optimiser steps (so weights differ from any fresh initialisation)."""
    root = make_synthetic_dataset(tmp_path_factory.mktemp("hub") / "ds", TARGET_REPO, num_episodes=3, seed=2)
    torch.manual_seed(0)
    config = tiny_config(
        stage="policy",
        use_retrieval=False,
        prior_repo_id=PRIOR_REPO,
        prior_root=None,
        finetune_skills=False,
        repo_id="someone/skillret-test",
    )
    policy = build_policy(config, TARGET_REPO, root)
    optimizer = torch.optim.Adam(policy.get_optim_params())
    for seed in range(3):
        loss, _ = policy.forward(training_batch(config, TARGET_REPO, root, seed=seed))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return policy.eval()


def _rollout(policy: SkillRetPolicy, steps: int = 9) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    features = policy.config.input_features
    policy.reset()
    return [
        policy.select_action(
            {k: torch.randn(2, *features[k].shape, generator=generator) for k in policy.observation_keys}
        )
        for _ in range(steps)
    ]


def test_save_load_round_trip_is_bit_identical(trained, tmp_path):
    trained.save_pretrained(tmp_path / "pretrained_model")
    loaded = SkillRetPolicy.from_pretrained(tmp_path / "pretrained_model")
    assert loaded.config.stage == "policy" and loaded.config.horizon == trained.config.horizon
    for a, b in zip(_rollout(trained), _rollout(loaded), strict=True):
        assert torch.equal(a, b)
    state, loaded_state = trained.state_dict(), loaded.state_dict()
    assert state.keys() == loaded_state.keys()
    assert not any("sampler" in name or "source" in name for name in state)  # data objects stay out
    assert all(torch.equal(state[k], loaded_state[k]) for k in state)


def test_push_to_hub_uploads_everything_with_a_method_card(trained, tmp_path, monkeypatch):
    uploads: list[Path] = []

    def create_repo(self, repo_id, **kwargs):
        return SimpleNamespace(repo_id=repo_id)

    def upload_folder(self, *, repo_id, folder_path, **kwargs):
        copy = tmp_path / f"upload{len(uploads)}"
        shutil.copytree(folder_path, copy)
        uploads.append(copy)
        return SimpleNamespace(repo_url=SimpleNamespace(url=f"https://hub.invalid/{repo_id}"))

    validated = []
    monkeypatch.setattr(HfApi, "create_repo", create_repo)
    monkeypatch.setattr(HfApi, "upload_folder", upload_folder)
    monkeypatch.setattr(RepoCard, "validate", lambda self, *a, **k: validated.append(True))

    train_config = TrainPipelineConfig(dataset=DatasetConfig(repo_id=TARGET_REPO), policy=trained.config)
    trained.push_model_to_hub(train_config)
    preprocessor, postprocessor = make_skillret_pre_post_processors(trained.config)
    preprocessor.push_to_hub(trained.config.repo_id)
    postprocessor.push_to_hub(trained.config.repo_id)

    model = uploads[0]
    assert {"model.safetensors", "config.json", "train_config.json", "README.md"} <= {p.name for p in model.iterdir()}
    card = (model / "README.md").read_text()
    assert validated
    assert "skill-based imitation with retrieval" in card and TARGET_REPO in card and PRIOR_REPO in card
    assert "skillret" in card
    assert (uploads[1] / "policy_preprocessor.json").is_file() and (uploads[2] / "policy_postprocessor.json").is_file()
    # what was uploaded loads back into the same behaviour
    for a, b in zip(_rollout(trained), _rollout(SkillRetPolicy.from_pretrained(model)), strict=True):
        assert torch.equal(a, b)


def test_a_stage1_card_names_the_prior_and_says_the_policy_is_untrained(tmp_path, monkeypatch):
    """A stage-1 run's --dataset is the prior: its card used to call it the target and the prior `none`."""
    monkeypatch.setattr(RepoCard, "validate", lambda self, *a, **k: None)  # it asks the Hub (offline here)
    root = make_synthetic_dataset(tmp_path / "prior", PRIOR_REPO, num_episodes=2, seed=0)
    policy = build_policy(tiny_config(), PRIOR_REPO, root)
    card = policy.generate_model_card(PRIOR_REPO, "skillret", None, None).content
    assert f"skills pre-trained on the prior dataset (`{PRIOR_REPO}`)" in card
    assert "latent policy is untrained" in card and "target dataset (`" not in card
