"""What was retrieved: a JSON summary and three plots, plus retrieval precision against primitive labels.

- `summary.json`: counts, the cut (largest retrieved distance), distance quantiles of all candidates and of the
  retrieved ones, how redundant the retrieved windows are (overlapping anchors of one episode), and per primitive
  its share among prior candidates, retrieved windows and target windows (when the datasets carry
  `primitive_index`; a window's primitive is the label of its anchor frame).
- `latents_pca.png`: prior (subsampled), target and retrieved latents on the first two principal axes.
- `distance_histogram.png`: distances of all candidates and of the retrieved ones, with the cut.
- `primitive_shares.png`: share of each primitive among prior / retrieved / target windows.

`retrieval_precision` is the share of retrieved windows whose primitive the target task uses; against the prior's
own share of those primitives (what uniform random retrieval gets in expectation) it measures retrieval quality.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from lerobot_skillret.data.retrieval_file import RetrievalResult
from lerobot_skillret.files import write_atomic, write_text_atomic
from lerobot_skillret.retrieval.kernels import Selection

QUANTILES = (0.0, 0.01, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.99, 1.0)
PCA_PRIOR_POINTS = 5000
PCA_RETRIEVED_POINTS = 3000


def retrieval_precision(primitive: Tensor, relevant: Iterable[str], names: Sequence[str]) -> float:
    """Share of windows (given by their primitive labels) whose primitive name is in `relevant`."""
    wanted = relevant_labels(relevant, names)
    if primitive.numel() == 0:
        return float("nan")
    return float(torch.isin(primitive.to(torch.int64), wanted).double().mean())


def relevant_labels(relevant: Iterable[str], names: Sequence[str]) -> Tensor:
    """Label values of the `relevant` primitive names (a clear error for a name the dataset does not have)."""
    relevant = list(relevant)
    unknown = sorted(set(relevant) - set(names))
    if unknown:
        raise ValueError(f"Unknown primitive name(s) {unknown}; the dataset's primitives are {list(names)}.")
    return torch.tensor([names.index(name) for name in relevant], dtype=torch.int64)


# --- summary ------------------------------------------------------------------------------------------------


@dataclass
class ReportInputs:
    """What the report needs beyond the retrieval file: every candidate's score, latent and labels."""

    selection: Selection
    prior_mean: Tensor  # [N, D] candidates' latents
    target_mean: Tensor  # [M, D]
    anchors: Tensor  # [N] global frame index of each candidate's anchor
    episode_start: Tensor | None = None  # [N] first frame of each candidate's episode
    primitive: Tensor | None = None  # [N] primitive label at each candidate's anchor frame
    target_primitive: Tensor | None = None  # [M] primitive label at each target window's anchor frame
    primitive_names: list[str] | None = None
    relevant_primitives: list[str] | None = None


def summarize(result: RetrievalResult, inputs: ReportInputs | None) -> dict[str, Any]:
    """The JSON summary (see the module docstring); `inputs` is None for the "no retrieval" mode."""
    settings = result.settings
    summary: dict[str, Any] = {
        "mode": settings.get("mode"),
        "metric": settings.get("metric"),
        "fraction": settings.get("fraction"),
        "retrieved": len(result),
        "candidates": settings.get("num_candidates", 0),
        "target_windows": settings.get("num_target_windows", 0),
    }
    if inputs is None:
        return summary
    selection = inputs.selection
    distance = selection.distance
    retrieved = distance[selection.retrieved]
    summary["cut"] = selection.cut
    summary["distance_quantiles"] = {"candidates": _quantiles(distance), "retrieved": _quantiles(retrieved)}
    summary["mean_distance"] = {
        "candidates": float(distance.mean()) if distance.numel() else float("nan"),
        "retrieved": float(retrieved.mean()) if retrieved.numel() else float("nan"),
    }
    summary["targets_used"] = int(torch.unique(selection.nearest).numel())
    if inputs.episode_start is not None:
        summary["redundancy"] = _redundancy(
            inputs.anchors[selection.retrieved], inputs.episode_start[selection.retrieved], settings.get("horizon", 1)
        )
    if inputs.primitive is not None:
        summary["primitives"] = _primitive_shares(inputs)
        if inputs.relevant_primitives:
            names = _names(inputs)
            summary["precision"] = {
                "relevant": list(inputs.relevant_primitives),
                "retrieved": retrieval_precision(
                    inputs.primitive[selection.retrieved], inputs.relevant_primitives, names
                ),
                "candidates": retrieval_precision(inputs.primitive, inputs.relevant_primitives, names),
            }
    return summary


def _quantiles(values: Tensor) -> dict[str, float]:
    """Exact quantiles (linear interpolation) of any number of values, by NumPy: `torch.quantile` refuses inputs
    over 2^24 elements, which a large prior exceeds."""
    if values.numel() == 0:
        return {}
    q = np.quantile(values.double().flatten().numpy(), QUANTILES)
    return {f"{level:g}": float(v) for level, v in zip(QUANTILES, q, strict=True)}


def _redundancy(anchors: Tensor, episode_start: Tensor, horizon: int) -> dict[str, float]:
    """Share of retrieved windows overlapping another retrieved one (same episode, anchors < H steps apart)."""
    if anchors.numel() < 2:
        return {"overlapping_share": 0.0, "episodes": int(torch.unique(episode_start).numel())}
    order = torch.argsort(anchors)
    a, s = anchors[order], episode_start[order]
    close = (torch.diff(a) < horizon) & (s[1:] == s[:-1])
    overlapping = torch.zeros(len(a), dtype=torch.bool)
    overlapping[1:] |= close
    overlapping[:-1] |= close
    return {"overlapping_share": float(overlapping.double().mean()), "episodes": int(torch.unique(s).numel())}


def label_names(known: Sequence[str] | None, *labels: Tensor | None) -> list[str]:
    """Names for every label value present: the dataset's own names, then "primitive <i>" for the rest."""
    count = max((int(x.max()) + 1 for x in labels if x is not None and x.numel()), default=0)
    names = list(known or [])
    return names + [f"primitive {i}" for i in range(len(names), count)]


def _names(inputs: ReportInputs) -> list[str]:
    return label_names(inputs.primitive_names, inputs.primitive, inputs.target_primitive)


def _primitive_shares(inputs: ReportInputs) -> list[dict[str, Any]]:
    names = _names(inputs)

    def shares(labels: Tensor | None) -> list[float] | None:
        if labels is None or labels.numel() == 0:
            return None
        return (torch.bincount(labels, minlength=len(names)).double() / labels.numel()).tolist()

    prior = shares(inputs.primitive)
    retrieved = shares(inputs.primitive[inputs.selection.retrieved])
    target = shares(inputs.target_primitive)
    return [
        {
            "label": i,
            "name": name,
            "prior_share": prior[i],
            "retrieved_share": retrieved[i] if retrieved else None,
            "target_share": target[i] if target else None,
        }
        for i, name in enumerate(names)
    ]


# --- files --------------------------------------------------------------------------------------------------


def write_report(report_dir: str | Path, result: RetrievalResult, inputs: ReportInputs | None) -> dict[str, Path]:
    """Write summary.json and, when anything was scored, the three plots. Returns the written paths."""
    report_dir = Path(report_dir)
    report_dir.mkdir(parents=True, exist_ok=True)
    summary = summarize(result, inputs)
    paths = {"summary": report_dir / "summary.json"}

    write_text_atomic(paths["summary"], json.dumps(summary, indent=1, allow_nan=True) + "\n")
    if inputs is None or inputs.selection.distance.numel() == 0:
        return paths
    import matplotlib

    matplotlib.use("Agg")
    paths["latents_pca"] = _save_figure(report_dir / "latents_pca.png", _pca_figure(inputs, summary))
    paths["distance_histogram"] = _save_figure(
        report_dir / "distance_histogram.png", _histogram_figure(inputs, summary)
    )
    if "primitives" in summary:
        paths["primitive_shares"] = _save_figure(report_dir / "primitive_shares.png", _primitive_figure(summary))
    return paths


def _save_figure(path: Path, figure) -> Path:
    import matplotlib.pyplot as plt

    try:
        return write_atomic(path, lambda tmp: figure.savefig(tmp, dpi=110, bbox_inches="tight", format="png"))
    finally:
        plt.close(figure)


def _title(summary: dict[str, Any]) -> str:
    return (
        f"mode {summary['mode']}, {summary['metric']}, r={summary['fraction']:.0%}: {summary['retrieved']:,} of "
        f"{summary['candidates']:,} prior windows, {summary['target_windows']:,} target windows"
    )


def _subsample(rows: Tensor, count: int, seed: int) -> Tensor:
    if len(rows) <= count:
        return rows
    return rows[torch.randperm(len(rows), generator=torch.Generator().manual_seed(seed))[:count]]


def _pca_figure(inputs: ReportInputs, summary: dict[str, Any]):
    import matplotlib.pyplot as plt

    prior_rows = _subsample(torch.arange(inputs.prior_mean.shape[0]), PCA_PRIOR_POINTS, 0)
    retrieved_rows = _subsample(inputs.selection.retrieved, PCA_RETRIEVED_POINTS, 1)
    fit = torch.cat([inputs.prior_mean[prior_rows], inputs.target_mean]).double()
    center = fit.mean(0)
    # Two principal axes of prior and target together (exact SVD: the fitted set is at most a few thousand rows).
    _, singular, axes = torch.linalg.svd(fit - center, full_matrices=False)
    explained = (singular**2 / (singular**2).sum())[:2].tolist()
    axes = axes[:2].t()

    def project(x: Tensor) -> Tensor:
        return ((x.double() - center) @ axes).numpy()

    figure, ax = plt.subplots(figsize=(7.5, 6))
    prior_xy = project(inputs.prior_mean[prior_rows])
    ax.scatter(prior_xy[:, 0], prior_xy[:, 1], s=4, c="0.75", alpha=0.5, lw=0, label="prior (candidates)")
    # Target first, thin and light, so the retrieved windows drawn over it stay visible where the two overlap.
    target_xy = project(inputs.target_mean)
    ax.scatter(target_xy[:, 0], target_xy[:, 1], s=10, c="tab:red", marker="x", lw=0.5, alpha=0.35, label="target")
    retrieved_xy = project(inputs.prior_mean[retrieved_rows])
    ax.scatter(retrieved_xy[:, 0], retrieved_xy[:, 1], s=7, c="tab:blue", alpha=0.8, lw=0, label="retrieved")
    ax.set_xlabel(f"PC 1 ({explained[0]:.0%} of variance)")
    ax.set_ylabel(f"PC 2 ({explained[1]:.0%} of variance)" if len(explained) > 1 else "PC 2")
    ax.set_title("Skill latents (encoder means)\n" + _title(summary), fontsize=9)
    ax.legend(markerscale=3, loc="best", fontsize=8)
    return figure


def _histogram_figure(inputs: ReportInputs, summary: dict[str, Any]):
    import matplotlib.pyplot as plt

    distance = inputs.selection.distance.double().numpy()
    retrieved = inputs.selection.distance[inputs.selection.retrieved].double().numpy()
    figure, ax = plt.subplots(figsize=(7.5, 4.5))
    bins = torch.linspace(float(distance.min()), float(distance.max()) + 1e-12, 81).numpy()
    ax.hist(distance, bins=bins, color="0.7", label=f"all candidates ({len(distance):,})")
    ax.hist(retrieved, bins=bins, color="tab:blue", label=f"retrieved ({len(retrieved):,})")
    if len(retrieved):
        ax.axvline(summary["cut"], color="tab:red", ls="--", lw=1.2, label=f"cut = {summary['cut']:.3g}")
    unit = "L2 distance" if summary["metric"] == "l2" else "symmetric KL"
    ax.set_xlabel(f"{unit} to the nearest target latent")
    ax.set_ylabel("prior windows")
    ax.set_title(_title(summary), fontsize=9)
    ax.legend(fontsize=8)
    return figure


def _primitive_figure(summary: dict[str, Any]):
    import matplotlib.pyplot as plt

    rows = summary["primitives"]
    relevant = set(summary.get("precision", {}).get("relevant", []))
    series = [("prior (all candidates)", "prior_share", "0.6"), ("retrieved", "retrieved_share", "tab:blue")]
    if rows and rows[0]["target_share"] is not None:
        series.append(("target", "target_share", "tab:red"))
    x = np.arange(len(rows))
    width = 0.8 / len(series)
    figure, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(rows) + 2), 4.5))
    for k, (label, key, color) in enumerate(series):
        values = [row[key] or 0.0 for row in rows]
        ax.bar(x + (k - (len(series) - 1) / 2) * width, values, width, label=label, color=color)
    ax.set_xticks(x, [row["name"] + (" *" if row["name"] in relevant else "") for row in rows], rotation=20, ha="right")
    ax.set_ylabel("share of windows")
    title = "Primitive of each window (label at its anchor frame)"
    if "precision" in summary:
        p = summary["precision"]
        title += f"\n* = used by the target task: precision {p['retrieved']:.0%} vs {p['candidates']:.0%} in prior"
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    return figure
