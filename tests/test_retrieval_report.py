"""The report on hand-made inputs: numbers in summary.json are the ones computed by hand; plots are PNGs."""

from __future__ import annotations

import json

import pytest
import torch

from lerobot_skillret.data.retrieval_file import RetrievalResult
from lerobot_skillret.retrieval.kernels import Selection
from lerobot_skillret.retrieval.report import QUANTILES, ReportInputs, _quantiles, label_names, write_report


def inputs_and_result():
    # 8 candidates in two episodes (frames 0-4 and 5-9); retrieved: anchors 0, 2 (overlap, H=4), 7, 9 (overlap).
    anchors = torch.tensor([0, 1, 2, 3, 5, 6, 7, 9])
    episode_start = torch.tensor([0, 0, 0, 0, 5, 5, 5, 5])
    distance = torch.tensor([0.1, 0.9, 0.2, 0.8, 0.7, 0.6, 0.3, 0.4], dtype=torch.float64)
    retrieved = torch.tensor([0, 2, 6, 7])
    selection = Selection(distance=distance, retrieved=retrieved, nearest=torch.tensor([0, 1, 1, 1]))
    primitive = torch.tensor([0, 0, 1, 1, 2, 2, 2, 0])
    inputs = ReportInputs(
        selection=selection,
        prior_mean=torch.randn(8, 3),
        target_mean=torch.randn(2, 3),
        anchors=anchors,
        episode_start=episode_start,
        primitive=primitive,
        target_primitive=torch.tensor([1, 2]),
        primitive_names=["reach", "grasp"],
        relevant_primitives=["grasp"],
    )
    settings = {
        "mode": "nearest",
        "metric": "l2",
        "fraction": 0.5,
        "num_candidates": 8,
        "num_target_windows": 2,
        "horizon": 4,
    }
    result = RetrievalResult(anchors[retrieved], distance[retrieved].float(), torch.zeros(4, 3), settings)
    return inputs, result


def test_summary_numbers_and_plots(tmp_path):
    inputs, result = inputs_and_result()
    paths = write_report(tmp_path / "report", result, inputs)
    summary = json.loads(paths["summary"].read_text())
    assert summary["retrieved"] == 4 and summary["candidates"] == 8 and summary["cut"] == pytest.approx(0.4)
    assert summary["mean_distance"]["retrieved"] == pytest.approx(0.25)
    assert summary["distance_quantiles"]["candidates"]["1"] == pytest.approx(0.9)
    assert summary["targets_used"] == 2
    assert summary["redundancy"] == {"overlapping_share": 1.0, "episodes": 2}
    shares = {row["name"]: row for row in summary["primitives"]}
    assert list(shares) == ["reach", "grasp", "primitive 2"]
    assert shares["grasp"]["prior_share"] == pytest.approx(2 / 8)
    assert shares["grasp"]["retrieved_share"] == pytest.approx(1 / 4)  # labels of retrieved: 0, 1, 2, 0
    assert shares["primitive 2"]["target_share"] == pytest.approx(0.5)
    assert summary["precision"] == {"relevant": ["grasp"], "retrieved": 0.25, "candidates": 0.25}
    for name in ("latents_pca", "distance_histogram", "primitive_shares"):
        assert paths[name].read_bytes()[:4] == b"\x89PNG"
    assert not [p for p in paths["summary"].parent.iterdir() if p.name.startswith(".")]


def test_no_retrieval_report_has_counts_only(tmp_path):
    _, result = inputs_and_result()
    paths = write_report(
        tmp_path,
        RetrievalResult(result.prior_index[:0], result.distance[:0], result.latent[:0], {"mode": "none"}),
        None,
    )
    assert list(paths) == ["summary"]
    assert json.loads(paths["summary"].read_text())["retrieved"] == 0


def test_label_names_fill_unnamed_labels():
    assert label_names(None, torch.tensor([0, 2])) == ["primitive 0", "primitive 1", "primitive 2"]
    assert label_names(["a"], torch.tensor([1]), None) == ["a", "primitive 1"]


def test_distance_quantiles_are_exact_beyond_torch_quantiles_limit():
    values = torch.rand(1001, generator=torch.Generator().manual_seed(0))
    expected = torch.quantile(values.double(), torch.tensor(QUANTILES, dtype=torch.float64))
    assert list(_quantiles(values).values()) == pytest.approx(expected.tolist(), abs=1e-12)
    # torch.quantile refuses more than 2^24 values; every candidate of a large prior still counts
    many = torch.arange((1 << 24) + 1, dtype=torch.float32).flip(0)
    assert _quantiles(many)["0.5"] == 1 << 23 and _quantiles(many)["1"] == 1 << 24
