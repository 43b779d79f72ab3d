"""The retrieval file: what stage 2 (policy learning) consumes from the retrieval engine.

A single safetensors file, written atomically:

tensors
    prior_index  int64   [K]     global frame index (LeRobotDataset `index`) of each retrieved window's anchor,
                                 i.e. the first step o_t of its H-step sub-trajectory in the prior dataset
    distance     float32 [K]     its distance to the nearest target latent (metric in `settings`: the L2 norm,
                                 or the symmetric KL); rows are sorted by it, closest first
    latent       float32 [K, D]  its skill latent (encoder mean) at retrieval time
metadata (all strings)
    schema_version              "1"
    settings                    JSON: the resolved `RetrievalSettings` (mode, fraction, metric, num_prior,
                                 num_target, seed, and the options beyond the paper), plus what `retrieve`
                                 observed: checkpoint, prior_repo_id, target_repo_id, horizon, latent_dim,
                                 num_prior_frames, num_target_frames, num_candidates, num_target_windows,
                                 num_retrieved, cut (largest retrieved distance)
    checkpoint_fingerprint      `checkpoint_fingerprint()` of the stage-1 checkpoint that encoded the windows
    prior_fingerprint           `dataset_fingerprint()` of the prior dataset
    target_fingerprint          `dataset_fingerprint()` of the target dataset

Stage 2 recomputes the anchors' windows (F preceding observations, H steps) from the prior dataset itself; the
file only says which windows. An empty selection (K = 0) is valid and means "no retrieval".
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file

from lerobot_skillret.files import write_atomic

SCHEMA_VERSION = "1"


@dataclass
class RetrievalResult:
    prior_index: torch.Tensor
    distance: torch.Tensor
    latent: torch.Tensor
    settings: dict[str, Any] = field(default_factory=dict)
    checkpoint_fingerprint: str = ""
    prior_fingerprint: str = ""
    target_fingerprint: str = ""

    def __post_init__(self) -> None:
        k = self.prior_index.shape[0]
        if (
            self.prior_index.ndim != 1
            or self.distance.shape != (k,)
            or self.latent.ndim != 2
            or (self.latent.shape[0] != k)
        ):
            raise ValueError(
                "RetrievalResult needs prior_index [K], distance [K] and latent [K, D]; got "
                f"{tuple(self.prior_index.shape)}, {tuple(self.distance.shape)}, {tuple(self.latent.shape)}."
            )

    def __len__(self) -> int:
        return int(self.prior_index.shape[0])

    def save(self, path: str | Path) -> Path:
        """Write to a temporary file beside `path`, then rename: a crash never leaves a half-written file."""
        tensors = {
            "prior_index": self.prior_index.to(torch.int64).contiguous(),
            "distance": self.distance.to(torch.float32).contiguous(),
            "latent": self.latent.to(torch.float32).contiguous(),
        }
        metadata = {
            "schema_version": SCHEMA_VERSION,
            "settings": json.dumps(self.settings, sort_keys=True),
            "checkpoint_fingerprint": self.checkpoint_fingerprint,
            "prior_fingerprint": self.prior_fingerprint,
            "target_fingerprint": self.target_fingerprint,
        }
        return write_atomic(path, lambda tmp: save_file(tensors, tmp, metadata=metadata))

    @classmethod
    def load(cls, path: str | Path) -> RetrievalResult:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(
                f"Retrieval file {path} does not exist. Run `skillret-retrieve` first, or disable retrieval "
                "(--policy.use_retrieval=false) for the paper's 'no retrieval' ablation."
            )
        try:
            with safe_open(str(path), framework="pt") as handle:  # one read for metadata and tensors
                metadata = handle.metadata() or {}
                tensors = {name: handle.get_tensor(name) for name in handle.keys()}  # noqa: SIM118 (safe_open is not iterable)
        except SafetensorError as error:
            raise ValueError(
                f"Retrieval file {path} cannot be read ({error}): it is truncated or corrupt. Re-run "
                "`skillret-retrieve` to regenerate it."
            ) from None
        version = metadata.get("schema_version")
        if version != SCHEMA_VERSION:
            raise ValueError(
                f"{path} has retrieval schema version {version!r}; this skillret reads version "
                f"{SCHEMA_VERSION!r}. Re-run `skillret-retrieve` to regenerate it."
            )
        return cls(
            prior_index=tensors["prior_index"],
            distance=tensors["distance"],
            latent=tensors["latent"],
            settings=json.loads(metadata.get("settings", "{}")),
            checkpoint_fingerprint=metadata.get("checkpoint_fingerprint", ""),
            prior_fingerprint=metadata.get("prior_fingerprint", ""),
            target_fingerprint=metadata.get("target_fingerprint", ""),
        )

    def check_compatible(
        self,
        *,
        prior_fingerprint: str | None = None,
        target_fingerprint: str | None = None,
        checkpoint_fingerprint: str | None = None,
    ) -> None:
        """Refuse a file computed on other data or another skill checkpoint than the one being used."""
        for name, stored, expected in (
            ("prior dataset", self.prior_fingerprint, prior_fingerprint),
            ("target dataset", self.target_fingerprint, target_fingerprint),
            ("stage-1 checkpoint", self.checkpoint_fingerprint, checkpoint_fingerprint),
        ):
            if expected is not None and stored != expected:
                raise ValueError(
                    f"The retrieval file was computed on a different {name} (fingerprint {stored or 'missing'}, "
                    f"this run uses {expected}). Re-run `skillret-retrieve` with the {name} of this run."
                )
