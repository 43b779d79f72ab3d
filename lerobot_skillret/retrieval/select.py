"""Which scored prior windows are retrieved (Algorithm 2, line 6, and the options beyond the paper).

- `smallest`: the paper's rule, the `count` smallest scores. float32 scores carry an error bound per row; only
  rows whose side of the cut is uncertain are re-scored in float64, so the set equals a float64 brute force.
- `greedy`: walk the candidates in a given order (by score, or random for the "random retrieval" ablation) and
  keep a window unless an option forbids it, until `count` are kept:
  * temporal non-maximum suppression (`nms_radius` k): overlapping windows of one episode carry nearly the same
    behaviour; once a window is kept, windows of the same episode whose anchors lie within k steps are skipped.
  * a per-target quota (`target_quota` q): each target latent may be the nearest one of at most q kept windows,
    so one over-represented target behaviour cannot take the whole budget.
  Skipped windows are replaced by the next ones in the order, so the count stays the same.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from lerobot_skillret.retrieval.kernels import Scores


def retrieval_count(fraction: float, num_candidates: int) -> int:
    """K = round(r * candidates) (Algorithm 2's n); r must be a share in [0, 1]."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"The retrieval fraction r={fraction} must be in [0, 1] (0.1 keeps the closest 10%).")
    return round(fraction * num_candidates)


def smallest(scores: Scores, count: int, exact: Callable[[Tensor], Tensor] | None = None) -> tuple[Tensor, Tensor]:
    """Rows of the `count` smallest values, sorted by value, and those values (float64).

    With `exact` (rows -> float64 values), the rows whose error margin straddles the cut are re-scored exactly,
    which makes the set the one a float64 computation would select (ties broken by row).
    """
    value, num = scores.value.to(torch.float64, copy=True), scores.value.shape[0]
    if not 0 <= count <= num:
        raise ValueError(f"Cannot select {count} of {num} candidates.")
    if exact is not None and 0 < count < num:
        margin = scores.margin.to(torch.float64)
        low, high = value - margin, value + margin
        # Every value moved by at most its margin, so the exact count-th smallest lies in [cut_low, cut_high]:
        # rows entirely below cut_low are in, rows entirely above cut_high are out, the rest is re-scored.
        cut_low = torch.kthvalue(low, count).values
        cut_high = torch.kthvalue(high, count).values
        sure_in = high < cut_low
        band = torch.nonzero(~sure_in & (low <= cut_high)).squeeze(1)
        value[band] = exact(band).to(torch.float64)
        sure_rows = torch.nonzero(sure_in).squeeze(1)
        rows = torch.cat([sure_rows, _first(band, value[band], count - sure_rows.shape[0])])
    else:
        rows = torch.topk(value, count, largest=False, sorted=False).indices
    order = torch.sort(value[rows], stable=True).indices
    return rows[order], value[rows[order]]


def _first(rows: Tensor, values: Tensor, count: int) -> Tensor:
    """The `count` rows of smallest value, ties broken by row (rows are ascending)."""
    return rows[torch.sort(values, stable=True).indices[:count]]


def greedy(
    order: Tensor,
    count: int,
    *,
    anchors: Tensor | None = None,
    episode_start: Tensor | None = None,
    episode_end: Tensor | None = None,
    nms_radius: int = 0,
    nearest: Tensor | None = None,
    target_quota: int | None = None,
) -> Tensor:
    """Candidates (positions into the candidate arrays) kept when walking `order`, at most `count` of them.

    `anchors`, `episode_start`, `episode_end` (per candidate: global frame index of its anchor, and of its
    episode's first / one-past-last frame) are needed for `nms_radius` > 0; `nearest` (per candidate: index of
    its nearest target latent) for `target_quota`.
    """
    if nms_radius < 0:
        raise ValueError(f"nms_radius must be >= 0 steps (0 disables suppression); got {nms_radius}.")
    if target_quota is not None and target_quota < 1:
        raise ValueError(f"target_quota must be >= 1 window per target latent (or None); got {target_quota}.")
    if nms_radius and (anchors is None or episode_start is None or episode_end is None):
        raise ValueError("Temporal suppression needs the anchors and episode bounds of the candidates.")
    if target_quota is not None and nearest is None:
        raise ValueError("A per-target quota needs each candidate's nearest target index.")
    if not nms_radius and target_quota is None:
        return order[:count].clone()
    if count == 0:
        return torch.empty(0, dtype=torch.int64)
    kept: list[int] = []
    # A plain Python walk: it stops after `count` keeps, and each step is a few list look-ups.
    blocked = bytearray(int(episode_end.max()) if nms_radius else 0)
    anchor_of = anchors.tolist() if nms_radius else None
    start_of = episode_start.tolist() if nms_radius else None
    end_of = episode_end.tolist() if nms_radius else None
    nearest_of = nearest.tolist() if target_quota is not None else None
    used = [0] * (int(nearest.max()) + 1) if target_quota is not None else None
    for position in order.tolist():
        if nms_radius:
            frame = anchor_of[position]
            if blocked[frame]:
                continue
        if target_quota is not None:
            target = nearest_of[position]
            if used[target] >= target_quota:
                continue
            used[target] += 1
        if nms_radius:
            low = max(start_of[position], frame - nms_radius)
            high = min(end_of[position], frame + nms_radius + 1)
            blocked[low:high] = b"\x01" * (high - low)
        kept.append(position)
        if len(kept) == count:
            break
    return torch.tensor(kept, dtype=torch.int64)
