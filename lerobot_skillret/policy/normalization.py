"""The skill model's own normalisation: statistics held as persistent buffers inside the policy.

Why not LeRobot's processor: `lerobot-train --policy.path=<stage 1>` replaces the processor's statistics with the
target dataset's, which would silently rescale the actions a pre-trained decoder emits. Buffers travel in
`model.safetensors` instead: set once from the stage-1 dataset, then kept through stage 2, evaluation and the hub.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np
import torch
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from torch import Tensor, nn

MIN_SCALE = 1e-2  # floor of a std / half-range: a dimension constant in stage-1 data must not explode later
MODES = (NormalizationMode.MEAN_STD, NormalizationMode.MIN_MAX)  # the code each mode is stored under


def _buffer_name(key: str) -> str:
    return key.replace(".", "__")


class SkillNormalizer(nn.Module):
    """x_norm = (x - shift) / scale per feature, from MEAN_STD (mean, std) or MIN_MAX statistics.

    MIN_MAX maps [min, max] onto [-(1 - margin), 1 - margin]. The margin is folded into the stored scale, so a
    checkpoint acts the same whatever margin a later config asks for.

    Until statistics are set the buffers hold NaN, and `check_ready` refuses to train or act on them.

    Each feature's mode is stored with its statistics, and loading a checkpoint whose modes differ from the config's
    fails: the decoder's head follows the action mode (tanh or linear), so a silent swap would mis-scale every action.
    """

    def __init__(
        self,
        features: Mapping[str, PolicyFeature],
        mapping: Mapping[str, NormalizationMode],
        stats: Mapping[str, Mapping[str, object]] | None = None,
        min_max_margin: float = 0.0,
    ) -> None:
        super().__init__()
        self.min_max_margin = min_max_margin
        self.register_buffer("device_marker", torch.empty(0), persistent=False)  # the policy's device, cheaply
        self.modes: dict[str, NormalizationMode] = {}
        for key, feature in features.items():
            mode = NormalizationMode(mapping.get(feature.type.value, NormalizationMode.IDENTITY))
            if feature.type is FeatureType.VISUAL or mode is NormalizationMode.IDENTITY:
                continue
            self.modes[key] = mode
            dim = int(np.prod(feature.shape))
            self.register_buffer(f"{_buffer_name(key)}_shift", torch.full((dim,), torch.nan))
            self.register_buffer(f"{_buffer_name(key)}_scale", torch.full((dim,), torch.nan))
            self.register_buffer(f"{_buffer_name(key)}_mode", torch.tensor([MODES.index(mode)]))
        if stats is not None:
            self.set_stats(stats)

    def set_stats(self, stats: Mapping[str, Mapping[str, object]]) -> None:
        """Copy dataset statistics (LeRobot's `meta.stats` layout) into the buffers."""
        layout = (
            "a policy started from a checkpoint (--policy.path) needs a dataset with the checkpoint's observation and "
            "action layout (same robot, keys and sizes): record the target like the prior, or train stage 1 on data "
            "with this dataset's layout"
        )
        for key, mode in self.modes.items():
            if key not in stats:
                raise ValueError(
                    f"skillret normalisation: the dataset has no statistics for `{key}`, a feature the policy reads; "
                    f"{layout}."
                )
            entry = {
                name: torch.as_tensor(np.asarray(value), dtype=torch.float32).reshape(-1)
                for name, value in stats[key].items()
                if name in ("mean", "std", "min", "max")
            }
            if not all(torch.isfinite(value).all() for value in entry.values()):
                raise ValueError(
                    f"skillret normalisation: the dataset statistics of `{key}` hold NaN or inf, so the dataset has "
                    "non-finite values in that feature: regenerate the dataset or drop the episodes that hold them."
                )
            size = getattr(self, f"{_buffer_name(key)}_shift").numel()
            other = next((value.numel() for value in entry.values() if value.numel() != size), None)
            if other is not None:
                raise ValueError(
                    f"skillret normalisation: the dataset's `{key}` has {other} values per frame, the policy's "
                    f"{size}; {layout}."
                )
            if mode is NormalizationMode.MEAN_STD:
                shift, scale = entry["mean"], entry["std"]
            else:
                shift = (entry["max"] + entry["min"]) / 2
                scale = (entry["max"] - entry["min"]) / 2 / (1.0 - self.min_max_margin)
            getattr(self, f"{_buffer_name(key)}_shift").copy_(shift)
            getattr(self, f"{_buffer_name(key)}_scale").copy_(scale.clamp_min(MIN_SCALE))

    def _load_from_state_dict(self, state_dict, prefix, local_metadata, strict, missing, unexpected, errors):
        """Refuse a checkpoint normalised otherwise than the config says (loading is non-strict in LeRobot)."""

        def stored(suffix: str) -> dict[str, Tensor]:
            return {
                name.removeprefix(prefix).removesuffix(suffix): value
                for name, value in state_dict.items()
                if name.startswith(prefix) and name.endswith(suffix)
            }

        wanted = {_buffer_name(key): mode.value for key, mode in self.modes.items()}
        found = {name: MODES[int(code)].value for name, code in stored("_mode").items()}
        if not found and (shifted := stored("_shift")):  # saved before the modes were recorded
            logging.warning("skillret: the checkpoint does not record its normalisation modes; assuming %s", wanted)
            found = {name: wanted.get(name, "unrecorded") for name in shifted}
        if found != wanted:
            errors.append(
                f"skillret normalisation: the checkpoint normalises {found or 'nothing'} but the config asks for "
                f"{wanted or 'nothing'}. The modes are fixed by stage 1: drop the `skill_normalization_mapping` "
                "override, or train stage 1 again with the new mapping."
            )
        super()._load_from_state_dict(state_dict, prefix, local_metadata, strict, missing, unexpected, errors)

    def check_ready(self) -> None:
        """Refuse NaN statistics: a policy built without dataset stats and without loaded weights."""
        for key in self.modes:
            if torch.isnan(getattr(self, f"{_buffer_name(key)}_shift")).any():
                raise RuntimeError(
                    f"skillret has no normalisation statistics for `{key}`: build it with the stage-1 dataset's "
                    "stats (lerobot-train does) or load a trained checkpoint (from_pretrained / --policy.path)."
                )

    def normalize(self, key: str, value: Tensor) -> Tensor:
        if key not in self.modes:
            return value
        name = _buffer_name(key)
        return (value - self._buffers[f"{name}_shift"]) / self._buffers[f"{name}_scale"]

    def unnormalize(self, key: str, value: Tensor) -> Tensor:
        if key not in self.modes:
            return value
        name = _buffer_name(key)
        return value * self._buffers[f"{name}_scale"] + self._buffers[f"{name}_shift"]
