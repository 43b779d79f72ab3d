"""Distance from every prior latent to its nearest target latent, in bounded memory, and the r closest.

Algorithm 2 (lines 4-5) needs, for each of N prior windows, the distance to the closest of M target windows. The
N x M matrix is never built: prior rows are scored in chunks of `chunk_size`, each chunk with ONE matrix product
into a reused [chunk, M] buffer followed by a row minimum, so peak memory is O(chunk * M) whatever N is.

Both metrics are written as `d(i, j) = F_i . G_j + a_i + b_j` (features F of a prior row, G of a target row,
per-row constants a, b): the product absorbs b_j through an extra column of ones, and a_i is added after the
minimum (it does not change which j is nearest).

- "l2": squared Euclidean distance of the encoder means, ||p||^2 - 2 p.q + ||q||^2 (the paper's metric; the
  reported distance is its square root). Both sets are centred first: this keeps the cancellation error small.
- "kl": the symmetric KL of two diagonal Gaussians, 0.5 (KL(q1||q2) + KL(q2||q1)) (appendix A.2). Per dimension
  it is 0.25 (v1/v2 + v2/v1 + (m1 - m2)^2 (1/v1 + 1/v2) - 2): the log-determinants cancel, and expanding the
  square leaves four products of a prior feature with a target feature, i.e. one product over 4 D features.

The chunks run in float32 (the GEMM is the cost). Each row also gets a rigorous-style bound on its float32 error
(`Scores.margin`), which `smallest` (Algorithm 2, line 6) uses to re-score in float64 only the few rows whose side
of the cut is uncertain: the selected set then equals a float64 brute-force computation.

`Selection` is what `api.select_windows` makes of the scores (and what the report reads).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import torch
from torch import Tensor
from tqdm.auto import tqdm

from lerobot_skillret.policy.configuration_skillret import RETRIEVAL_METRICS as METRICS

_UNIT_ROUNDOFF = {torch.float32: 2.0**-24, torch.float64: 2.0**-53}
_EXACT_SLICE = 1 << 16  # prior rows gathered at once by `exact`


@dataclass
class Scores:
    """Per prior row: the metric value to its nearest target, that target's index, and an error bound."""

    value: Tensor  # [N] (the run's dtype): squared L2 or symmetric KL to the nearest target latent
    nearest: Tensor | None  # [N] int64: index of the nearest target latent (only when asked: it costs ~30%)
    margin: Tensor  # [N]: |value - exact value| <= margin (0-ish for a float64 run)


@dataclass
class Selection:
    """Scores of every candidate and which candidates are retrieved."""

    distance: Tensor  # [N] float64: L2 distance (or symmetric KL) of each candidate to its nearest target
    retrieved: Tensor  # [K] int64: positions into the candidates, sorted by distance (ascending)
    nearest: Tensor  # [K] int64: index of the target latent nearest to each retrieved window

    @property
    def cut(self) -> float:
        """Largest distance among the retrieved windows (nan when nothing is retrieved)."""
        return float(self.distance[self.retrieved].max()) if len(self.retrieved) else float("nan")


def check_latents(mean: Tensor, log_var: Tensor | None, metric: str, name: str, check_finite: bool = True) -> None:
    """Reject shapes and values the kernels would otherwise turn into silent nonsense.

    `check_finite=False` skips the NaN/inf scan (the prior's is done on the scores instead: N values, not N x D).
    """
    if metric not in METRICS:
        raise ValueError(f"Unknown retrieval metric {metric!r}: choose one of {METRICS}.")
    if mean.ndim != 2:
        raise ValueError(f"{name} latents must be a [num_windows, latent_dim] matrix; got {tuple(mean.shape)}.")
    if check_finite:
        for values in (mean, log_var):
            if values is not None and not bool(torch.isfinite(values).all()):
                raise _non_finite(name)
    if metric == "kl":
        if log_var is None:
            raise ValueError(
                f"The 'kl' metric needs the encoder log-variances of the {name} windows; pass {name}_log_var "
                "(or use metric 'l2')."
            )
        if log_var.shape != mean.shape:
            raise ValueError(f"{name} log-variances {tuple(log_var.shape)} do not match the means {tuple(mean.shape)}.")


@contextmanager
def single_threaded() -> Iterator[int]:
    """Run torch ops on one intra-op thread inside the block; yields the previous thread count.

    Why: on a shared machine, OpenMP's barrier-synchronised threads wait for each other whenever one of them is
    descheduled, so every small parallel region can cost a scheduler time slice. Measured under load on 2 cores,
    one OpenMP-parallel scoring pass took 10-16 s where two independent single-threaded workers (`run_workers`)
    took 2.4-3.1 s; on an idle machine both reach about twice the speed of one thread.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield previous
    finally:
        torch.set_num_threads(previous)


def run_workers(work: Callable[[int, int], None], workers: int) -> None:
    """Run `work(i, workers)` for i < workers on Python threads (torch releases the GIL inside its kernels)."""
    if workers <= 1:
        work(0, 1)
        return
    with ThreadPoolExecutor(workers) as pool:
        for future in [pool.submit(work, i, workers) for i in range(workers)]:
            future.result()


def _non_finite(name: str) -> ValueError:
    return ValueError(
        f"The {name} latents contain NaN/inf (or overflow the metric): the stage-1 checkpoint's encoder diverged "
        f"or the {name} data has extreme values. Check the skills run's losses and the dataset."
    )


class NearestTarget:
    """Scores prior latents against a fixed set of target latents (Algorithm 2, lines 2-5)."""

    def __init__(self, target_mean: Tensor, target_log_var: Tensor | None = None, *, metric: str = "l2") -> None:
        check_latents(target_mean, target_log_var, metric, "target")
        if target_mean.shape[0] == 0:
            raise ValueError(
                "The target set is empty: retrieval needs at least one target window (is the target dataset "
                "empty, or --num-target 0?)."
            )
        self.metric = metric
        self.target_mean = target_mean.detach().to(torch.float64)
        self.target_log_var = None if target_log_var is None else target_log_var.detach().to(torch.float64)

    @property
    def latent_dim(self) -> int:
        return self.target_mean.shape[1]

    def _check_prior(self, prior_mean: Tensor, prior_log_var: Tensor | None) -> None:
        check_latents(prior_mean, prior_log_var if self.metric == "kl" else None, self.metric, "prior", False)
        if prior_mean.shape[1] != self.latent_dim:
            raise ValueError(
                f"Prior latents have dimension {prior_mean.shape[1]} but target latents {self.latent_dim}: both "
                "must be encoded by the same stage-1 checkpoint."
            )

    # --- features ---------------------------------------------------------------------------------------------

    def _prior_features(self, mean: Tensor, log_var: Tensor | None, center: Tensor, out: Tensor) -> Tensor:
        """Write the features F of a chunk of prior rows into `out` [n, E] and return a [n], both in out's dtype."""
        dim, dtype = self.latent_dim, out.dtype
        centered = out[:, :dim] if self.metric == "l2" else out[:, 3 * dim :]
        torch.sub(mean.to(dtype), center.to(dtype), out=centered)
        square = centered * centered
        if self.metric == "l2":
            return square.sum(1)
        log_var = log_var.to(dtype)
        inv = torch.exp(torch.neg(log_var), out=out[:, dim : 2 * dim])
        torch.add(torch.exp(log_var), square, out=out[:, :dim])
        torch.mul(centered, inv, out=out[:, 2 * dim : 3 * dim])
        return 0.25 * (square * inv).sum(1)

    def _target_features(self, center: Tensor) -> tuple[Tensor, Tensor]:
        """(G [M, E], b [M]) in float64; the KL scale 0.25 and its constant -D/2 are folded in here."""
        m = self.target_mean - center
        if self.metric == "l2":
            return -2.0 * m, (m * m).sum(1)
        inv = torch.exp(-self.target_log_var)
        var = torch.exp(self.target_log_var)
        features = 0.25 * torch.cat([inv, var + m * m, -2.0 * m, -2.0 * m * inv], dim=1)
        return features, 0.25 * ((m * m * inv).sum(1) - 2.0 * self.latent_dim)

    # --- scoring ----------------------------------------------------------------------------------------------

    def score(
        self,
        prior_mean: Tensor,
        prior_log_var: Tensor | None = None,
        *,
        chunk_size: int = 256,
        dtype: torch.dtype = torch.float32,
        with_nearest: bool = False,
        progress: bool = False,
    ) -> Scores:
        """Score every prior row; memory beyond the inputs is O(chunk_size * M), never O(N * M).

        `with_nearest` also returns each row's nearest target index (a row minimum with its position is ~30%
        slower than the plain minimum, so it is off unless the caller needs it for most rows)."""
        with single_threaded() as threads:  # parallel over chunks instead (see `single_threaded`)
            self._check_prior(prior_mean, prior_log_var)
            if chunk_size < 1:
                raise ValueError(f"chunk_size must be >= 1; got {chunk_size}.")
            num_prior, num_target = prior_mean.shape[0], self.target_mean.shape[0]
            center = self._center(prior_mean)
            target_features, target_const = self._target_features(center)
            width = target_features.shape[1]
            # Augmented target matrix [E + 1, M]: its last row meets a column of ones and adds b_j.
            target_aug = torch.cat([target_features, target_const[:, None]], dim=1).t().contiguous().to(dtype)
            chunk_size = min(chunk_size, max(num_prior, 1))
            value = torch.empty(num_prior, dtype=dtype)
            nearest = torch.empty(num_prior, dtype=torch.int64) if with_nearest else None
            margin = torch.empty(num_prior, dtype=dtype)
            # Error bound: gamma_n (sum_e |F_ie G_je| + |b_j|) <= gamma_n (||F_i|| max||G_j|| + max|b_j|), plus the
            # roundings of the inputs and of the final additions; doubled for safety.
            gamma = 2.0 * (width + 6) * _UNIT_ROUNDOFF[dtype]
            target_norm_max = float(target_features.norm(dim=1).max())
            target_const_max = float(target_const.abs().max())
            bar = tqdm(
                total=-(-num_prior // chunk_size),
                desc=f"scoring prior windows ({self.metric})",
                disable=not progress,
                unit="chunk",
            )

            def work(worker: int, workers: int) -> None:
                """Chunks worker, worker + workers, ... with this worker's own buffers (reused across its chunks)."""
                torch.set_num_threads(1)  # per thread: a fresh pool thread may not inherit the caller's setting
                prior_aug = torch.ones(chunk_size, width + 1, dtype=dtype)
                buffer = torch.empty(chunk_size, num_target, dtype=dtype)
                for start in range(worker * chunk_size, num_prior, workers * chunk_size):
                    stop = min(start + chunk_size, num_prior)
                    rows = prior_aug[: stop - start]
                    log_var = None if prior_log_var is None else prior_log_var[start:stop]
                    const = self._prior_features(prior_mean[start:stop], log_var, center, rows[:, :width])
                    block = buffer[: stop - start]
                    torch.mm(rows, target_aug, out=block)
                    if nearest is None:
                        best = torch.amin(block, dim=1)
                    else:
                        best, nearest[start:stop] = torch.min(block, dim=1)
                    total = torch.add(best, const, out=value[start:stop])
                    norm = const.sqrt() if self.metric == "l2" else rows[:, :width].norm(dim=1)
                    bound = norm.mul_(target_norm_max).add_(target_const_max).add_(const.abs()).add_(total.abs())
                    torch.mul(bound, gamma, out=margin[start:stop])
                    bar.update(1)

            run_workers(work, min(threads, bar.total or 1))
            bar.close()
            # A NaN/inf in a prior latent makes its row's value NaN/inf (they propagate through the product).
            if not bool(torch.isfinite(value).all()):
                raise _non_finite("prior")
        return Scores(value=value, nearest=nearest, margin=margin)

    def exact(self, prior_mean: Tensor, prior_log_var: Tensor | None, rows: Tensor, chunk_size: int = 256) -> Tensor:
        """float64 values of the given prior rows: settles the rows whose side of the selection cut is uncertain.

        Rows are gathered a slice at a time, so even a degenerate case (every row uncertain) stays in bounded
        memory; it then costs about twice the float32 pass."""
        out = torch.empty(len(rows), dtype=torch.float64)
        for start in range(0, len(rows), _EXACT_SLICE):
            part = rows[start : start + _EXACT_SLICE]
            log_var = None if prior_log_var is None else prior_log_var[part]
            scores = self.score(prior_mean[part], log_var, chunk_size=chunk_size, dtype=torch.float64)
            out[start : start + len(part)] = scores.value
        return out

    def _center(self, prior_mean: Tensor, rows: int = 1 << 16) -> Tensor:
        """Mean of prior and target latents together (float64, one chunked pass over the prior, no copy)."""
        total = self.target_mean.sum(0)
        for start in range(0, prior_mean.shape[0], rows):
            total = total + prior_mean[start : start + rows].sum(0, dtype=torch.float64)
        return total / (prior_mean.shape[0] + self.target_mean.shape[0])


def smallest(scores: Scores, count: int, exact: Callable[[Tensor], Tensor] | None = None) -> tuple[Tensor, Tensor]:
    """Rows of the `count` smallest values, sorted by value, and those values (float64): Algorithm 2, line 6.

    With `exact` (rows -> float64 values, e.g. `NearestTarget.exact`), the rows whose error margin straddles the
    cut are re-scored exactly, which makes the set the one a float64 computation would select (ties broken by row).
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
        # The rest of the count: the band's smallest exact values, ties broken by row (band rows are ascending).
        rest = band[torch.sort(value[band], stable=True).indices[: count - sure_rows.shape[0]]]
        rows = torch.cat([sure_rows, rest])
    else:
        rows = torch.topk(value, count, largest=False, sorted=False).indices
    order = torch.sort(value[rows], stable=True).indices
    return rows[order], value[rows[order]]
