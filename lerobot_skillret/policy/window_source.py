"""Windows the policy fetches itself during training: what `lerobot-train`'s single dataloader cannot give.

`lerobot-train` feeds `forward` windows of ONE dataset (`--dataset.*`). The method also needs, per batch, the
paired window at offset d of the same episode (temporal prediction, Algorithm 1 line 3), and in stage 2 prior
windows (skill fine-tuning, Algorithm 2 line 17) and retrieved prior windows (lines 12, 14). They come from the
fast column sampler of `lerobot_skillret.data.windows`; camera frames, which that table does not hold,
are read through `LeRobotDataset` for exactly the windows sampled.

These objects are plain attributes of the policy, never modules: they stay out of the state_dict and checkpoints.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler


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
    ) -> None:
        self.repo_id, self.root = repo_id, Path(root)
        self.columns = EpisodeColumns.from_dataset(repo_id, self.root)
        # Seeded from torch's global RNG, which lerobot-train seeds with `--seed`: pairs and prior windows repeat.
        seed = int(torch.randint(0, 2**62, ()))
        self.sampler = WindowSampler(
            self.columns, history=history, horizon=horizon, keys=[*low_dim_keys, "action"], seed=seed
        )
        self.image_keys = list(image_keys)
        self._frames = None
        if self.image_keys:
            from lerobot.datasets.lerobot_dataset import LeRobotDataset

            fps = self.columns.fps
            offsets = [step / fps for step in range(-(history - 1), horizon)]
            self._frames = LeRobotDataset(
                repo_id, root=self.root, delta_timestamps=dict.fromkeys(self.image_keys, offsets)
            )

    def __len__(self) -> int:
        return len(self.columns)

    def gather(self, anchors: Tensor, device: torch.device | str) -> dict[str, Tensor]:
        """Windows at global frame positions `anchors` (B,), moved to `device`."""
        windows = self.sampler.gather(anchors.cpu())
        batch = {key: value.to(device) for key, value in windows.items()}
        if self._frames is not None:
            items = [self._frames[int(anchor)] for anchor in anchors.tolist()]
            for key in self.image_keys:
                batch[key] = torch.stack([item[key] for item in items]).to(device)
                batch[f"{key}_is_pad"] = torch.stack([item[f"{key}_is_pad"] for item in items]).to(device)
        return batch

    def sample(self, batch_size: int, device: torch.device | str) -> dict[str, Tensor]:
        return self.gather(self.sampler.sample_anchors(batch_size), device)

    def pair(self, anchors: Tensor, max_offset: int, device: torch.device | str) -> tuple[dict[str, Tensor], Tensor]:
        """The windows at a uniform offset d in [-max_offset, max_offset] within each anchor's episode, and d."""
        anchors2, offset = self.sampler.sample_pair_anchors(anchors.cpu(), max_offset)
        return self.gather(anchors2, device), offset.to(device)
