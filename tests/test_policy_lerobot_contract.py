"""LeRobot's own policy checks (the patterns of upstream's tests/policies/test_policies.py), run on `skillret`:
class/config resolution through LeRobot's factory, save/load, processors, and no mutation of the caller's inputs."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest
import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.policies.factory import get_policy_class, make_policy, make_policy_config, make_pre_post_processors
from policy_fixtures import PRIOR_REPO, build_policy, tiny_config, training_batch
from synthetic import make_synthetic_dataset

import lerobot_skillret  # noqa: F401  (registers the policy type, as LeRobot's plugin discovery does)
from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def prior_root(tmp_path_factory) -> Path:
    return make_synthetic_dataset(tmp_path_factory.mktemp("prior") / "ds", PRIOR_REPO, num_episodes=3, seed=0)


def _clone(batch: dict) -> dict:
    return {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in batch.items()}


def _assert_same(before: dict, after: dict) -> None:
    assert sorted(before) == sorted(after), "the policy added or removed keys of the caller's batch"
    for key, value in before.items():
        if isinstance(value, torch.Tensor):
            torch.testing.assert_close(after[key], value, rtol=0, atol=0, msg=f"`{key}` was modified in place")


def test_get_policy_and_config_classes():
    """Upstream's check: the class LeRobot resolves has the type's name, and its `config` annotation is the
    config class itself (a string annotation, from `from __future__ import annotations`, fails here)."""
    policy_cls = get_policy_class("skillret")
    policy_cfg = make_policy_config("skillret", device="cpu")
    assert policy_cls is SkillRetPolicy and policy_cls.name == "skillret"
    assert issubclass(policy_cfg.__class__, inspect.signature(policy_cls.__init__).parameters["config"].annotation)


def test_make_policy_and_processors_through_lerobots_factory(prior_root):
    """What lerobot-train does: features from the dataset's metadata, processors from the config's module."""
    meta = LeRobotDatasetMetadata(PRIOR_REPO, root=prior_root)
    config = tiny_config()
    policy = make_policy(config, ds_meta=meta)
    assert isinstance(policy, SkillRetPolicy)
    assert config.output_features["action"].type is FeatureType.ACTION
    assert {"observation.state", "observation.environment_state"} <= set(config.input_features)
    pre, post = make_pre_post_processors(config, dataset_stats=meta.stats)
    batch = training_batch(config, PRIOR_REPO, prior_root, size=4)
    processed = pre(_clone(batch))
    # the processor's normalisers are identities (the model owns its statistics): values pass through unchanged
    torch.testing.assert_close(processed["observation.state"], batch["observation.state"])
    action = torch.randn(2, config.output_features["action"].shape[0])
    torch.testing.assert_close(post(action.clone()), action)


def test_save_and_load_pretrained(prior_root, tmp_path):
    torch.manual_seed(0)
    policy = build_policy(tiny_config(), PRIOR_REPO, prior_root)
    policy.save_pretrained(tmp_path / "model")
    loaded = SkillRetPolicy.from_pretrained(tmp_path / "model")
    assert isinstance(loaded.config, SkillRetConfig) and loaded.config.horizon == policy.config.horizon
    expected, got = policy.state_dict(), loaded.state_dict()
    assert sorted(expected) == sorted(got)
    for key in expected:  # weights and the normalisation statistics the model owns
        torch.testing.assert_close(got[key], expected[key], rtol=0, atol=0, msg=key)


def test_processors_save_and_load(prior_root, tmp_path):
    meta = LeRobotDatasetMetadata(PRIOR_REPO, root=prior_root)
    config = tiny_config()
    pre, post = make_pre_post_processors(config, dataset_stats=meta.stats)
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    loaded_pre, loaded_post = make_pre_post_processors(config, pretrained_path=str(tmp_path))
    assert [type(s) for s in loaded_pre.steps] == [type(s) for s in pre.steps]
    assert [type(s) for s in loaded_post.steps] == [type(s) for s in post.steps]


@pytest.mark.parametrize("stage", ["skills", "policy"])
def test_forward_does_not_mutate_its_batch(prior_root, stage):
    config = tiny_config(stage=stage, use_retrieval=False, prior_repo_id=None)
    policy = build_policy(config, PRIOR_REPO, prior_root)
    batch = training_batch(config, PRIOR_REPO, prior_root, size=4)
    before = _clone(batch)
    loss, info = policy.forward(batch)
    assert loss.ndim == 0 and torch.isfinite(loss)
    assert all(isinstance(v, float) for v in info.values())
    _assert_same(before, batch)


def test_select_action_and_chunk_do_not_mutate_the_observation(prior_root):
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    frame = training_batch(config, PRIOR_REPO, prior_root, size=2)
    observation = {k: v[:, -1] for k, v in frame.items() if k.startswith("observation.") and not k.endswith("_pad")}
    before = _clone(observation)
    policy.reset()
    action = policy.select_action(observation)
    assert action.shape == (2, config.output_features["action"].shape[0])
    chunk = policy.predict_action_chunk(observation)
    assert chunk.shape == (2, config.horizon, config.output_features["action"].shape[0])
    _assert_same(before, observation)
