"""The retrieval file: round trip, atomic write, and clear refusals (missing, old version, other data)."""

from __future__ import annotations

import math

import pytest
import torch
from safetensors.torch import save_file

from lerobot_skillret.data.retrieval_file import RetrievalResult


def make_result(k: int = 5, dim: int = 4) -> RetrievalResult:
    return RetrievalResult(
        prior_index=torch.arange(k) * 3,
        distance=torch.linspace(0.1, 0.5, k),
        latent=torch.randn(k, dim),
        settings={"mode": "nearest", "fraction": 0.1, "cut": float("nan")},
        checkpoint_fingerprint="ckpt",
        prior_fingerprint="prior",
        target_fingerprint="target",
    )


def test_round_trip_and_no_temporary_files_left(tmp_path):
    result = make_result()
    path = result.save(tmp_path / "sub" / "ret.safetensors")
    loaded = RetrievalResult.load(path)
    assert torch.equal(loaded.prior_index, result.prior_index) and torch.equal(loaded.latent, result.latent)
    assert loaded.settings["mode"] == "nearest" and loaded.prior_fingerprint == "prior"
    assert [p.name for p in path.parent.iterdir()] == ["ret.safetensors"]
    empty = RetrievalResult(torch.empty(0, dtype=torch.int64), torch.empty(0), torch.empty(0, 4))
    assert len(RetrievalResult.load(empty.save(tmp_path / "empty.safetensors"))) == 0


def test_refusals_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="Run `skillret-retrieve` first"):
        RetrievalResult.load(tmp_path / "missing.safetensors")
    old = tmp_path / "old.safetensors"
    save_file({"prior_index": torch.zeros(1, dtype=torch.int64)}, str(old), metadata={"schema_version": "0"})
    with pytest.raises(ValueError, match="schema version '0'"):
        RetrievalResult.load(old)
    truncated = tmp_path / "truncated.safetensors"
    data = make_result().save(tmp_path / "whole.safetensors").read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"truncated\.safetensors cannot be read .* regenerate"):
        RetrievalResult.load(truncated)
    with pytest.raises(ValueError, match=r"needs prior_index \[K\], distance \[K\] and latent \[K, D\]"):
        RetrievalResult(torch.arange(3), torch.zeros(2), torch.zeros(3, 4))
    result = make_result()
    result.check_compatible(prior_fingerprint="prior", target_fingerprint="target", checkpoint_fingerprint="ckpt")
    for name, key in (("prior dataset", "prior"), ("target dataset", "target"), ("stage-1 checkpoint", "checkpoint")):
        with pytest.raises(ValueError, match=f"different {name}"):
            result.check_compatible(**{f"{key}_fingerprint": "other"})


def test_settings_with_nan_survive_a_round_trip(tmp_path):
    """An empty retrieval has no distance cut: its NaN must load back as NaN, not break the metadata JSON."""
    result = make_result()
    result.settings["cut"] = float("nan")
    loaded = RetrievalResult.load(result.save(tmp_path / "nan.safetensors"))
    assert math.isnan(loaded.settings["cut"]) and loaded.settings["mode"] == "nearest"
