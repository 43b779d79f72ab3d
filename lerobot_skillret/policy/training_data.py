"""Which extra windows each training stage reads, and from where (built once, on the first training forward).

Stage `skills`: temporal pairs from the training dataset itself.
Stage `policy`: temporal pairs from the target dataset (`--dataset.*`); prior windows for skill fine-tuning
(`prior_repo_id` / `prior_root`); retrieved windows: the prior windows listed in the retrieval file
(`retrieval_path`), checked against the datasets and the stage-1 checkpoint that produced it.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from lerobot_skillret.data.fingerprint import checkpoint_fingerprint
from lerobot_skillret.data.retrieval_file import RetrievalResult
from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.window_source import WindowSource, data_parallel_rank


@dataclass
class RetrievedWindows:
    """D_ret (Algorithm 2, line 7): prior windows at `prior_index` with the latents stored at retrieval time."""

    source: WindowSource
    prior_index: Tensor  # (K,) global frame index of each window's anchor in the prior dataset
    latent: Tensor  # (K, latent_dim)

    def sample(self, size: int, device: torch.device) -> tuple[dict[str, Tensor], Tensor]:
        """`size` retrieved windows drawn uniformly (with replacement) and their stored latents; drawn with the
        prior source's generator, so each data-parallel rank draws its own."""
        pick = torch.randint(0, len(self.prior_index), (size,), generator=self.source.sampler.generator)
        return self.source.gather(self.prior_index[pick], device), self.latent[pick].to(device)


@dataclass
class TrainingData:
    own: WindowSource
    prior: WindowSource | None = None
    retrieved: RetrievedWindows | None = None

    @classmethod
    def build(
        cls, config: SkillRetConfig, dataset: tuple[str, Path] | None, keys: tuple[list[str], list[str]]
    ) -> TrainingData:
        """Window sources for `config`'s stage: `dataset` is the training dataset's (repo_id, root), `keys` the
        policy's (low-dimensional, image) observation keys. A stage-2 run with retrieval records the stage-1
        checkpoint's fingerprint in `config` (saved in config.json, so a resumed run checks the same one)."""
        if dataset is None:
            raise RuntimeError(
                "skillret training fetches temporal pairs from the training dataset on disk, but the policy was "
                "built without `dataset_meta`. Train with lerobot-train (it passes it), or build the policy with "
                "SkillRetPolicy(config, dataset_stats=meta.stats, dataset_meta=LeRobotDatasetMetadata(repo_id, root))."
            )
        repo_id, root = dataset
        # the training dataset's own windows are only needed whole (history included) with `fast_windows`
        history = config.history if config.fast_windows and config.stage == "policy" else 1
        windows = {"horizon": config.horizon, "video_backend": config.video_backend}
        own = WindowSource(repo_id, root, *keys, history=history, **windows)
        if config.stage == "skills":
            return cls(own=own)

        prior = None
        if config.prior_repo_id is not None and (config.finetune_skills or config.use_retrieval):
            if config.prior_root is None:
                raise ValueError(
                    "`prior_root` is not set: skillret reads the prior dataset from disk. Pass "
                    "--policy.prior_root=<folder of the prior LeRobotDataset> (or --policy.prior_repo_id=null for "
                    "the 'no prior data' ablation)."
                )
            prior = WindowSource(config.prior_repo_id, config.prior_root, *keys, history=config.history, **windows)
        retrieved = cls._retrieved(config, own, prior) if config.use_retrieval else None
        return cls(own=own, prior=prior if config.finetune_skills else None, retrieved=retrieved)

    def check_ranks(self, anchors: Tensor) -> None:
        """Data-parallel runs: every rank must train on the same retrieved set and draw its own windows.

        Gathers each rank's retrieved set, sampler seeds and first batch `anchors`, refuses a shared retrieved set
        that differs or seeds that repeat, and logs them on the main process (the only one LeRobot lets log)."""
        rank, world = data_parallel_rank()
        if world == 1:
            return
        retrieved = None if self.retrieved is None else self.retrieved.prior_index
        mine = {
            "retrieved": None
            if retrieved is None
            else (len(retrieved), hashlib.sha1(retrieved.numpy().tobytes()).hexdigest()[:12]),
            "seeds": [source.seed for source in (self.own, self.prior) if source is not None],
            "anchors": anchors[:6].tolist(),
        }
        ranks: list[dict] = [{} for _ in range(world)]
        torch.distributed.all_gather_object(ranks, mine)
        if len({str(r["retrieved"]) for r in ranks}) > 1:
            raise RuntimeError(
                f"Data-parallel ranks read different retrieved sets ({[r['retrieved'] for r in ranks]}): every "
                "rank must read the same --policy.retrieval_path and prior dataset (storage all ranks share)."
            )
        if len({tuple(r["seeds"]) for r in ranks}) < world:
            raise RuntimeError(f"Data-parallel ranks share window seeds {[r['seeds'] for r in ranks]}.")
        if rank == 0:
            logging.info(
                "skillret data-parallel: %d ranks, same retrieved set (%s windows); per rank: %s",
                world,
                mine["retrieved"][0] if mine["retrieved"] else 0,
                "; ".join(f"rank {i}: seeds {r['seeds']}, first anchors {r['anchors']}" for i, r in enumerate(ranks)),
            )

    @staticmethod
    def _retrieved(config: SkillRetConfig, own: WindowSource, prior: WindowSource | None) -> RetrievedWindows | None:
        if prior is None:
            raise ValueError(
                "`use_retrieval` is true but `prior_repo_id` is not set: retrieval needs the prior dataset. Pass "
                "--policy.prior_repo_id and --policy.prior_root, or --policy.use_retrieval=false (no retrieval)."
            )
        if config.retrieval_path is None:
            raise ValueError(
                "`use_retrieval` is true but `retrieval_path` is not set. Run `skillret-retrieve` on the stage-1 "
                "checkpoint and pass --policy.retrieval_path=<file>, or --policy.use_retrieval=false."
            )
        if config.skills_checkpoint_fingerprint is None:
            if config.pretrained_path is None:
                raise ValueError(
                    "Retrieval latents come from a stage-1 skill checkpoint, but this stage-2 run starts from "
                    "scratch. Pass --policy.path=<stage-1 checkpoint>/pretrained_model."
                )
            config.skills_checkpoint_fingerprint = checkpoint_fingerprint(config.pretrained_path)
        result = RetrievalResult.load(config.retrieval_path)
        result.check_compatible(
            prior_fingerprint=prior.columns.fingerprint,
            target_fingerprint=own.columns.fingerprint,
            checkpoint_fingerprint=config.skills_checkpoint_fingerprint,
        )
        if len(result) == 0:
            if config.skill_finetune_windows == "retrieved":
                raise ValueError(
                    f"The retrieval file {config.retrieval_path} selects no window, so "
                    '`skill_finetune_windows="retrieved"` has no window to fine-tune the skills on. Retrieve more '
                    "(a larger --fraction in `skillret-retrieve`) or pass --policy.skill_finetune_windows=prior."
                )
            logging.warning(
                "skillret: the retrieval file %s selects no window; training without retrieved data.",
                config.retrieval_path,
            )
            return None
        if int(result.prior_index.min()) < 0 or int(result.prior_index.max()) >= len(prior):
            raise ValueError(
                f"The retrieval file {config.retrieval_path} indexes frames outside the prior dataset "
                f"(0..{len(prior) - 1}); it was computed on another dataset. Re-run `skillret-retrieve`."
            )
        if result.latent.shape[1] != config.latent_dim:
            raise ValueError(
                f"The retrieval file's latents have {result.latent.shape[1]} dimensions but `latent_dim` is "
                f"{config.latent_dim}: it was computed with another skill model. Re-run `skillret-retrieve`."
            )
        return RetrievedWindows(prior, result.prior_index, result.latent)
