"""Bad input gets an error that names the problem and the fix (and leaves nothing partial behind)."""

from __future__ import annotations

from pathlib import Path

import draccus
import pytest
import torch
from lerobot.configs.train import TrainPipelineConfig
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from policy_fixtures import PRIOR_REPO, TARGET_REPO, build_policy, tiny_config
from synthetic import make_synthetic_dataset

from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy
from lerobot_skillret.retrieval.cli import main as retrieve_main

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def prior_root(tmp_path_factory) -> Path:
    return make_synthetic_dataset(tmp_path_factory.mktemp("prior") / "ds", PRIOR_REPO, num_episodes=3, seed=0)


@pytest.fixture(scope="module")
def stage1(prior_root, tmp_path_factory) -> Path:
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("stage1") / "pretrained_model"
    build_policy(tiny_config(), PRIOR_REPO, prior_root).save_pretrained(folder)
    return folder


def _truncated_copy(stage1: Path, folder: Path) -> Path:
    folder.mkdir()
    for file in stage1.iterdir():
        data = file.read_bytes()
        (folder / file.name).write_bytes(data[: len(data) // 2] if file.name == "model.safetensors" else data)
    return folder


def test_truncated_weights_name_the_file(stage1, tmp_path):
    broken = _truncated_copy(stage1, tmp_path / "broken")
    with pytest.raises(ValueError, match=r"Cannot read the weights .*broken/model\.safetensors.*truncated or corrupt"):
        SkillRetPolicy.from_pretrained(broken)


def test_retrieve_names_a_truncated_checkpoint_and_writes_nothing(stage1, prior_root, tmp_path, capsys):
    broken = _truncated_copy(stage1, tmp_path / "broken")
    output = tmp_path / "out" / "retrieval.safetensors"
    argv = ["--checkpoint", str(broken), "--prior-root", str(prior_root), "--target-root", str(prior_root)]
    with pytest.raises(SystemExit) as exit_info:
        retrieve_main([*argv, "--prior-repo-id", PRIOR_REPO, "--target-repo-id", PRIOR_REPO, "--output", str(output)])
    assert exit_info.value.code == 2
    assert "truncated or corrupt" in capsys.readouterr().err
    assert not output.exists()


def test_stage2_on_a_target_with_another_action_size_names_the_features(stage1, tmp_path):
    """Before: a raw `load_state_dict` size mismatch."""
    target = make_synthetic_dataset(tmp_path / "target", TARGET_REPO, num_episodes=2, action_dim=5, seed=1)
    meta = LeRobotDatasetMetadata(TARGET_REPO, root=target)
    config = tiny_config(stage="policy")
    policy = build_policy(config, TARGET_REPO, target)  # features from the target, as lerobot-train sets them
    with pytest.raises(ValueError, match=r"action: checkpoint \(7,\) vs now \(5,\).*prior's observation and action"):
        SkillRetPolicy.from_pretrained(stage1, config=policy.config, dataset_stats=meta.stats, dataset_meta=meta)


def test_episodes_shorter_than_the_window_are_padded_with_a_warning(tmp_path, caplog):
    """Decision: keep them, padded past their end as LeRobot and the seed do, and say so (they were silent)."""
    from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler

    root = make_synthetic_dataset(tmp_path / "short", "test/short", num_episodes=3, min_len=4, max_len=6, seed=2)
    columns = EpisodeColumns.from_dataset("test/short", root)
    with caplog.at_level("WARNING"):
        window = WindowSampler(columns, history=1, horizon=10).gather(torch.tensor([0]))
    assert "3 of 3 episodes of test/short are shorter than the window (H=10" in caplog.text
    assert bool(window["action_is_pad"][0, -1])  # padded, and flagged so the losses mask it
    caplog.clear()
    with caplog.at_level("WARNING"):
        WindowSampler(columns, history=1, horizon=4)
    assert "shorter than the window" not in caplog.text


def test_nan_in_the_dataset_statistics_names_the_feature(prior_root):
    """A NaN in a dataset reaches its meta/stats.json: the policy is refused when built from it, naming the
    feature (not later as "no normalisation statistics")."""
    meta = LeRobotDatasetMetadata(PRIOR_REPO, root=prior_root)
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    stats = {key: dict(value) for key, value in meta.stats.items()}
    stats["observation.state"]["mean"] = stats["observation.state"]["mean"].copy()
    stats["observation.state"]["mean"][1] = float("nan")
    with pytest.raises(ValueError, match=r"statistics of `observation.state` hold NaN or inf.*regenerate"):
        SkillRetPolicy(policy.config, dataset_stats=stats, dataset_meta=meta)


def test_a_dataset_of_another_layout_than_the_checkpoint_is_named(prior_root):
    """Stage 2 from a checkpoint (--policy.path) on a target dataset with another state size or without a feature:
    lerobot-train hands the target's statistics to the checkpoint's config, which failed with a raw size mismatch
    ("The size of tensor a (6) must match ... (8)") or a KeyError about statistics."""
    meta = LeRobotDatasetMetadata(PRIOR_REPO, root=prior_root)
    config = build_policy(tiny_config(), PRIOR_REPO, prior_root).config
    wider = {key: dict(value) for key, value in meta.stats.items()}
    wider["observation.state"] = {name: [0.5] * 8 for name in ("mean", "std", "min", "max")}
    with pytest.raises(
        ValueError, match=r"dataset's `observation.state` has 8 values per frame, the policy's 6.*--policy.path"
    ):
        SkillRetPolicy(config, dataset_stats=wider, dataset_meta=meta)
    missing = {key: value for key, value in meta.stats.items() if key != "observation.environment_state"}
    with pytest.raises(ValueError, match=r"no statistics for `observation.environment_state`.*same robot, keys"):
        SkillRetPolicy(config, dataset_stats=missing, dataset_meta=meta)


def test_an_observation_of_another_shape_than_trained_is_named(prior_root):
    """An env giving other observations than the policy was trained on (another image size, another state layout)
    used to run silently (a larger image is centre-cropped) or fail deep in a reshape."""
    policy = build_policy(tiny_config(), PRIOR_REPO, prior_root).eval()
    (size,) = policy.config.input_features["observation.state"].shape
    observation = {key: torch.zeros(1, *policy.config.input_features[key].shape) for key in policy.observation_keys}
    observation["observation.state"] = torch.zeros(1, size + 2)
    with pytest.raises(
        ValueError, match=rf"trained on `observation.state` of shape \({size},\); got \(1, {size + 2}\)"
    ):
        policy.select_action(observation)


def test_sample_weighting_is_refused_with_the_reason(prior_root):
    """lerobot-train's --sample_weighting calls forward(batch, reduction="none")."""
    config = tiny_config()
    policy = build_policy(config, PRIOR_REPO, prior_root)
    with pytest.raises(ValueError, match=r"reduction='none'.*Train without --sample_weighting"):
        policy.forward({}, reduction="none")


def test_an_invalid_config_value_reaches_a_lerobot_train_user(caplog):
    """lerobot-train's parser turns the config's ValueError into "Couldn't instantiate class SkillRetConfig"; the
    reason must still be shown."""
    args = ["--policy.type=skillret", "--policy.horizon=0", "--dataset.repo_id=local/x", "--policy.push_to_hub=false"]
    with pytest.raises(draccus.utils.DecodingError, match="Couldn't instantiate class SkillRetConfig"):
        draccus.parse(TrainPipelineConfig, args=args)
    assert "skillret config: `horizon`=0 is invalid: it must be >= 1." in caplog.text
