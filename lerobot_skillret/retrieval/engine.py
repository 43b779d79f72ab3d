"""Retrieval on latents: candidates' scores -> the retrieved windows (Algorithm 2, lines 4-6, and options).

`select_windows` works on already-encoded latents and is the part the benchmarks and exactness tests exercise;
`lerobot_skillret.retrieval.api.retrieve` wraps it with checkpoint loading, window encoding and the output file.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lerobot_skillret.retrieval.kernels import NearestTarget, Scores
from lerobot_skillret.retrieval.select import greedy, retrieval_count, smallest
from lerobot_skillret.retrieval.settings import RetrievalSettings

# Offsets of the seed for independent random streams (candidates, targets, random mode, importance reference).
STREAM_CANDIDATES, STREAM_TARGETS, STREAM_RANDOM, STREAM_REFERENCE = 0, 1, 2, 3


def generator(seed: int, stream: int) -> torch.Generator:
    """A generator per purpose, so changing e.g. the mode does not change which anchors are candidates."""
    return torch.Generator().manual_seed(seed * 7919 + stream)


@dataclass
class Selection:
    """Scores of every candidate and which candidates are retrieved."""

    distance: Tensor  # [N] float64: L2 distance (or symmetric KL) of each candidate to its nearest target
    retrieved: Tensor  # [K] int64: positions into the candidates, sorted by distance (ascending)
    nearest: Tensor  # [K] int64: index of the target latent nearest to each retrieved window
    score: Tensor | None = None  # [N] float64: ranking score when it is not the distance (importance weighting)

    @property
    def cut(self) -> float:
        """Largest distance among the retrieved windows (nan when nothing is retrieved)."""
        return float(self.distance[self.retrieved].max()) if len(self.retrieved) else float("nan")


def select_windows(
    prior_mean: Tensor,
    target_mean: Tensor,
    settings: RetrievalSettings,
    *,
    prior_log_var: Tensor | None = None,
    target_log_var: Tensor | None = None,
    anchors: Tensor | None = None,
    episode_start: Tensor | None = None,
    episode_end: Tensor | None = None,
    progress: bool = False,
) -> Selection:
    """Score the N candidate latents against the M target latents and pick round(r * N) of them.

    `settings` must be resolved. `anchors` / `episode_start` / `episode_end` (per candidate, global frame indices)
    are only needed for temporal suppression (`nms_radius`).
    """
    settings.validate()
    log_vars = (prior_log_var, target_log_var) if settings.metric == "kl" else (None, None)
    engine = NearestTarget(target_mean, log_vars[1], metric=settings.metric, neighbors=settings.neighbors)
    num = prior_mean.shape[0]
    count = retrieval_count(settings.fraction, num) if settings.mode != "none" else 0
    # Nearest-target indices cost ~30% of the pass: get them for all rows only when the quota needs them or most
    # rows are retrieved anyway; otherwise only for the retrieved rows, afterwards.
    with_nearest = settings.target_quota is not None or count > num // 4
    scores = engine.score(
        prior_mean, log_vars[0], chunk_size=settings.chunk_size, with_nearest=with_nearest, progress=progress
    )
    distance = _distance(scores.value.to(torch.float64), settings.metric)
    constrained = settings.nms_radius > 0 or settings.target_quota is not None
    bounds = {"anchors": anchors, "episode_start": episode_start, "episode_end": episode_end}
    options = {"nms_radius": settings.nms_radius, "target_quota": settings.target_quota, "nearest": scores.nearest}
    score = None
    if settings.mode == "random":
        order = torch.randperm(num, generator=generator(settings.seed, STREAM_RANDOM))
        retrieved = greedy(order, count, **bounds, **options)
    elif settings.importance:
        score = _importance(prior_mean, log_vars[0], scores, target_mean.shape[0], settings)
        retrieved = greedy(torch.sort(score, stable=True).indices, count, **bounds, **options)
    elif constrained:
        retrieved = greedy(torch.sort(scores.value, stable=True).indices, count, **bounds, **options)
    else:
        exact = (lambda rows: engine.exact(prior_mean, log_vars[0], rows)) if settings.exact else None
        retrieved, values = smallest(scores, count, exact)
        distance[retrieved] = _distance(values, settings.metric)  # float64-settled values near the cut
    retrieved = retrieved[torch.sort(distance[retrieved], stable=True).indices]
    if scores.nearest is not None:
        nearest = scores.nearest[retrieved]
    else:
        log_var = None if log_vars[0] is None else log_vars[0][retrieved]
        nearest = engine.score(
            prior_mean[retrieved], log_var, chunk_size=settings.chunk_size, with_nearest=True
        ).nearest
    return Selection(distance=distance, retrieved=retrieved, nearest=nearest, score=score)


def _distance(value: Tensor, metric: str) -> Tensor:
    """Reported distance: the L2 norm (kernels work with its square), or the symmetric KL itself."""
    return value.clamp(min=0.0).sqrt() if metric == "l2" else value.clamp(min=0.0)


def _importance(
    prior_mean: Tensor, prior_log_var: Tensor | None, scores: Scores, num_target: int, settings: RetrievalSettings
) -> Tensor:
    """log(d_target / d_prior): a k-NN estimate of log p_prior / p_target, up to a constant (lower is better).

    The k-NN density estimate at x from a sample of size n is ~ k / (n * d_k(x)^D). The prior's density is
    estimated from a random reference subset of the candidates of the same size as the target set, so the sample
    sizes cancel and ranking by d_target / d_prior ranks by the density ratio. A reference row never matches
    itself. Plain nearest-distance ranking is the special case of a uniform prior density.
    """
    num = prior_mean.shape[0]
    size = min(num, max(num_target, settings.neighbors + 1))
    if size <= settings.neighbors:
        raise ValueError(f"Importance weighting needs more than neighbors={settings.neighbors} candidates; got {num}.")
    reference = torch.randperm(num, generator=generator(settings.seed, STREAM_REFERENCE))[:size]
    exclude = torch.full((num,), -1, dtype=torch.int64)
    exclude[reference] = torch.arange(size)
    log_var_ref = None if prior_log_var is None else prior_log_var[reference]
    ref_engine = NearestTarget(prior_mean[reference], log_var_ref, metric=settings.metric, neighbors=settings.neighbors)
    ref = ref_engine.score(prior_mean, prior_log_var, chunk_size=settings.chunk_size, exclude=exclude)
    tiny = 1e-12
    return torch.log(_distance(scores.value, settings.metric) + tiny) - torch.log(
        _distance(ref.value, settings.metric) + tiny
    )
