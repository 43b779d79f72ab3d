"""Helpers for the policy tests: tiny skillret configs, policies built like lerobot-train builds them, batches."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.utils.feature_utils import dataset_to_policy_features

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

PRIOR_REPO = "test/prior"
TARGET_REPO = "test/target"
HORIZON, HISTORY = 4, 3

# A few-step lerobot-train run on the documented CPU config, one intra-op thread (on a shared 2-core machine
# oversubscribed torch threads make tiny steps 20x slower), offline.
CPU_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "policy" / "cpu.json"
TRAIN_ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
QUICK_TRAIN = [
    f"--config_path={CPU_CONFIG}",
    "--policy.device=cpu",
    "--num_workers=0",
    "--steps=3",
    "--batch_size=4",
    "--save_freq=3",
]

# CLI form of TINY, for lerobot-train subprocesses.
TINY_CLI = [
    f"--policy.horizon={HORIZON}",
    f"--policy.history={HISTORY}",
    "--policy.latent_dim=8",
    "--policy.encoder_lstm_hidden=16",
    "--policy.decoder_lstm_hidden=16",
    "--policy.policy_lstm_hidden=16",
    "--policy.encoder_mlp=[16]",
    "--policy.decoder_mlp=[16]",
    "--policy.prior_mlp=[16]",
    "--policy.tc_mlp=[8]",
    "--policy.low_dim_mlp=[16]",
]


def unit_stats(features: dict) -> dict[str, dict[str, torch.Tensor]]:
    """Identity normalisation statistics (mean 0, std 1, range [-1, 1]) for checkpoints built without a dataset."""
    return {
        key: {
            "mean": torch.zeros(f.shape),
            "std": torch.ones(f.shape),
            "min": -torch.ones(f.shape),
            "max": torch.ones(f.shape),
        }
        for key, f in features.items()
    }


def tiny_config(**overrides) -> SkillRetConfig:
    values = dict(
        horizon=HORIZON,
        history=HISTORY,
        latent_dim=8,
        encoder_lstm_hidden=16,
        decoder_lstm_hidden=16,
        policy_lstm_hidden=16,
        encoder_mlp=(16,),
        decoder_mlp=(16,),
        prior_mlp=(16,),
        tc_mlp=(8,),
        low_dim_mlp=(16,),
        crop_shape=None,
        spatial_softmax_keypoints=4,
        device="cpu",
        push_to_hub=False,
    )
    values.update(overrides)
    return SkillRetConfig(**values)


def build_policy(config: SkillRetConfig, repo_id: str, root: Path) -> SkillRetPolicy:
    """Like lerobot's make_policy: features and stats from the dataset's metadata."""
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    return SkillRetPolicy(config, dataset_stats=meta.stats, dataset_meta=meta)


def training_batch(config: SkillRetConfig, repo_id: str, root: Path, size: int = 8, seed: int = 0) -> dict:
    """A batch exactly as lerobot-train's dataloader gives it (the config's delta indices), random frames."""
    frames = LeRobotDatasetMetadata(repo_id, root=root).total_frames
    indices = torch.randint(0, frames, (size,), generator=torch.Generator().manual_seed(seed)).tolist()
    return batch_at(config, repo_id, root, indices)


def batch_at(config: SkillRetConfig, repo_id: str, root: Path, indices: list[int]) -> dict:
    """The lerobot-train batch of the given global frame indices (to place windows across episode ends)."""
    fps = LeRobotDatasetMetadata(repo_id, root=root).fps
    deltas = None
    if config.observation_delta_indices is not None:  # None with `fast_windows`: single frames
        deltas = {key: [i / fps for i in config.observation_delta_indices] for key in config.input_features}
        deltas["action"] = [i / fps for i in config.action_delta_indices]
    dataset = LeRobotDataset(repo_id, root=root, delta_timestamps=deltas)
    return torch.utils.data.default_collate([dataset[i] for i in indices])


def write_retrieval(path: Path, stage1_dir: Path, prior_root: Path, target_root: Path, indices: list[int]) -> Path:
    """A retrieval file as `skillret-retrieve` writes it, selecting the prior windows at `indices`."""
    from lerobot_skillret.data.fingerprint import checkpoint_fingerprint, dataset_fingerprint
    from lerobot_skillret.data.retrieval_file import RetrievalResult
    from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler

    stage1 = SkillRetPolicy.from_pretrained(stage1_dir)
    sampler = WindowSampler(EpisodeColumns.from_dataset(PRIOR_REPO, prior_root), history=HISTORY, horizon=HORIZON)
    latent, _ = stage1.encode_skill(sampler.gather(torch.tensor(indices)))
    return RetrievalResult(
        prior_index=torch.tensor(indices),
        distance=torch.zeros(len(indices)),
        latent=latent,
        settings={"metric": "l2"},
        checkpoint_fingerprint=checkpoint_fingerprint(stage1_dir),
        prior_fingerprint=dataset_fingerprint(prior_root),
        target_fingerprint=dataset_fingerprint(target_root),
    ).save(path)


def stage2_cli(stage1: Path, target: Path, prior: Path, retrieval: Path, output_dir: Path) -> list[str]:
    """lerobot-train options of a stage-2 run from `stage1` on `target`, with prior and retrieved windows."""
    return [
        f"--policy.path={stage1}",
        "--policy.stage=policy",
        f"--dataset.repo_id={TARGET_REPO}",
        f"--dataset.root={target}",
        f"--output_dir={output_dir}",
        f"--policy.prior_repo_id={PRIOR_REPO}",
        f"--policy.prior_root={prior}",
        f"--policy.retrieval_path={retrieval}",
    ]
