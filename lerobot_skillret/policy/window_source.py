"""Windows the policy fetches itself during training: what `lerobot-train`'s single dataloader cannot give.

`lerobot-train` feeds `forward` windows of ONE dataset (`--dataset.*`). The method also needs, per batch, the
paired window at offset d of the same episode (temporal prediction, Algorithm 1 line 3), and in stage 2 prior
windows (skill fine-tuning, Algorithm 2 line 17) and retrieved prior windows (lines 12, 14). They come from the
fast column sampler of `lerobot_skillret.data.windows`; camera frames, which that table does not hold,
are decoded by its `FrameReader` (LeRobot's own decoders, each distinct frame once) for exactly the windows sampled.

These objects are plain attributes of the policy, never modules: they stay out of the state_dict and checkpoints.

Data-parallel training (`accelerate launch --multi_gpu ... lerobot-train`) seeds every rank identically; LeRobot's
sharded dataloader then gives each rank different anchors, but the windows fetched here would repeat across ranks.
Each source's seed is therefore offset by the process's rank.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from lerobot_skillret.data.windows import EpisodeColumns, FrameReader, WindowSampler


class WindowSource:
    """Raw windows (history F, horizon H) of one local LeRobotDataset, keyed like a `lerobot-train` batch."""

    def __init__(
        self,
        repo_id: str,
        root: str | Path,
        low_dim_keys: list[str],
        image_keys: list[str],
        history: int,
        horizon: int,
        video_backend: str | None = None,
    ) -> None:
        self.columns = EpisodeColumns.from_dataset(repo_id, Path(root))
        frames = FrameReader(repo_id, Path(root), list(image_keys), video_backend) if image_keys else None
        self.seed = window_seed()
        self.sampler = WindowSampler(
            self.columns,
            history=history,
            horizon=horizon,
            keys=[*low_dim_keys, "action"],
            seed=self.seed,
            frames=frames,
        )

    def __len__(self) -> int:
        return len(self.columns)

    def gather(self, anchors: Tensor, device: torch.device | str) -> dict[str, Tensor]:
        """Windows at global frame positions `anchors` (B,), moved to `device`."""
        return {key: value.to(device) for key, value in self.sampler.gather(anchors.cpu()).items()}

    def sample(self, batch_size: int, device: torch.device | str) -> dict[str, Tensor]:
        return self.gather(self.sampler.sample_anchors(batch_size), device)

    def pair(self, anchors: Tensor, max_offset: int, device: torch.device | str) -> tuple[dict[str, Tensor], Tensor]:
        """The windows at a uniform offset d in [-max_offset, max_offset] within each anchor's episode, and d."""
        anchors2, offset = self.sampler.sample_pair_anchors(anchors.cpu(), max_offset)
        return self.gather(anchors2, device), offset.to(device)


def data_parallel_rank() -> tuple[int, int]:
    """(rank, world size) of this process in torch.distributed's default group; (0, 1) when not distributed."""
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


def window_seed() -> int:
    """A sampler seed from torch's global RNG (lerobot-train seeds it with `--seed`, so runs repeat), offset by the
    data-parallel rank (every rank gets the same `--seed`, and must still draw its own windows)."""
    rank, _ = data_parallel_rank()
    return (int(torch.randint(0, 2**62, ())) + rank) % 2**63
