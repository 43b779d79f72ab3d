"""Time and peak extra memory of retrieval (Algorithm 2, lines 4-6) on random latents, printed as one table.

    .venv/bin/python benchmarks/retrieval_speed.py                  # everything (minutes: the 2.3M rows dominate)
    .venv/bin/python benchmarks/retrieval_speed.py --public-sizes   # without the 5 GB dense float64 baseline
    .venv/bin/python benchmarks/retrieval_speed.py --sizes 250000 --kl-sizes --public-sizes   # L2 vs cdist (~1 min)

Each method runs in a fresh subprocess, so its peak resident memory is its own: "extra MiB" is the growth of the
process's peak RSS (`ru_maxrss`, which also sees torch's allocations, unlike tracemalloc) from just after the
latents were created to the end of the method. "time s" is the wall time of the best of `--repeats` runs (the
machine is shared with other jobs; the best run is the least disturbed one) and "cpu s" that run's process CPU
time (user + system, all threads): on a loaded machine cpu s / threads estimates the undisturbed wall time. Rows:

- skillret l2 / kl: `api.select_windows` (chunked float32 GEMM + row minimum, float64 settling of rows near the
  cut, top-r selection); N prior x M target latents of dimension D.
- chunked torch.cdist (the fair bounded-memory baseline, `--cdist-sizes`, default: the L2 sizes): float32
  `torch.cdist(prior_chunk, targets).amin(1)` over chunks of `--cdist-chunk` prior rows, then `torch.topk`; no
  float64 settling, so its set may differ from float64's at near ties. Each N with both rows gets a
  "cdist / skillret" line with the two measured ratios (wall time and CPU time) from the same run.
- public (dense float64 cdist): the public implementation's approach, the full N x M float64 matrix from
  `scipy.spatial.distance.cdist`, then the row minimum and an argsort. It is also the float64 reference: the
  "same set" column says whether the other rows selected exactly its windows.

Measured 2026-11-22 on the project's idle 2-core CPU (load average < 1), `--repeats 2`:

    method                                  N   time s    cpu s  extra MiB  same set as float64
    skillret L2 (chunked GEMM)        250,000     0.69     1.15         80                  yes
    skillret L2 (chunked GEMM)      2,300,000     5.72    10.15        260                    -
    skillret symmetric KL             250,000     1.65     3.07         50   n/a (other metric)
    public: dense float64 cdist       250,000    25.26    25.26       4892          (reference)

Under load (average 6-9 from other jobs) the same rows took 5.3 / 59 / 15 / 55 s wall: cpu s is the steadier figure.

Chunked torch.cdist against skillret L2, `--sizes 250000 --kl-sizes --public-sizes --repeats 2 [--cdist-chunk C]`,
measured 2026-11-30 on the same 2-core CPU while another job kept one core busy (load average ~4-5; each pair of rows
comes from one run, so both were disturbed alike). Two runs per chunk size:

    method                                      N   time s    cpu s  extra MiB
    skillret L2 (chunked GEMM)            250,000     3.34     2.15         81
    chunked torch.cdist (4096 rows)       250,000     8.35     6.48         54   -> 2.50x wall, 3.01x CPU
    skillret L2 (chunked GEMM)            250,000     4.40     2.78         89
    chunked torch.cdist (4096 rows)       250,000    10.93     7.19         54   -> 2.48x wall, 2.59x CPU
    skillret L2 (chunked GEMM)            250,000     4.32     2.67         80
    chunked torch.cdist (16384 rows)      250,000     6.91     4.46        194   -> 1.60x wall, 1.67x CPU
    skillret L2 (chunked GEMM)            250,000     2.10     2.06         82
    chunked torch.cdist (16384 rows)      250,000     7.52     4.99        194   -> 3.59x wall, 2.42x CPU

So against a bounded-memory baseline the kernel is ~1.7-3x faster in CPU time (against the dense float64 row of
the first table: 37x wall, 22x CPU), and it selects the float64 set exactly. At N = 50,000
(`--sizes 50000 --kl-sizes --public-sizes 50000`) both chunked rows matched the float64 set, and cdist with
4096-row chunks took 1.92x the wall time and 2.13x the CPU time.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SEED = 0
CDIST_CHUNK = 4096  # prior rows per torch.cdist block of the baseline: [4096, M] float32 (~40 MB at M = 2,500)


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux reports KiB


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _latents(num_prior: int, num_target: int, dim: int):
    import torch

    generator = torch.Generator().manual_seed(SEED)
    prior = torch.randn(num_prior, dim, generator=generator)
    target = torch.randn(num_target, dim, generator=generator) * 0.8 + 0.3
    prior_log_var = target_log_var = None
    return prior, target, prior_log_var, target_log_var, generator


def _select(method: str, prior, target, prior_log_var, target_log_var, fraction: float):
    """Positions of the retrieved prior rows by one method."""
    import numpy as np

    if method.startswith("skillret"):
        from lerobot_skillret.retrieval.api import select_windows
        from lerobot_skillret.retrieval.settings import RetrievalSettings

        metric = "kl" if method == "skillret-kl" else "l2"
        settings = RetrievalSettings(fraction=fraction, metric=metric, num_prior=len(prior)).resolve()
        selection = select_windows(prior, target, settings, prior_log_var=prior_log_var, target_log_var=target_log_var)
        return selection.retrieved.numpy()
    if method.startswith("cdist"):  # "cdist-<chunk rows>"
        import torch

        chunk = int(method.split("-")[1])
        nearest = torch.empty(len(prior))
        for start in range(0, len(prior), chunk):
            nearest[start : start + chunk] = torch.cdist(prior[start : start + chunk], target).amin(1)
        return torch.topk(nearest, round(fraction * len(prior)), largest=False).indices.numpy()
    if method == "public":
        from scipy.spatial.distance import cdist

        distances = cdist(prior.numpy().astype(np.float64), target.numpy().astype(np.float64))  # [N, M] float64
        nearest = distances.min(axis=1)
        return np.argsort(nearest, kind="stable")[: round(fraction * len(prior))]
    raise ValueError(f"unknown method {method}")


def run_method(
    method: str, num_prior: int, num_target: int, dim: int, fraction: float, out: Path, repeats: int
) -> dict:
    """Runs inside the child process: build the inputs, then time one method and measure its memory growth."""
    import numpy as np
    import torch

    if method.startswith("skillret"):  # imports (lerobot is heavy) stay out of both the time and the memory
        import lerobot_skillret.retrieval.api  # noqa: F401
    elif method == "public":
        import scipy.spatial.distance  # noqa: F401
    prior, target, prior_log_var, target_log_var, generator = _latents(num_prior, num_target, dim)
    if method == "skillret-kl":
        prior_log_var = -1.0 + 0.3 * torch.randn(num_prior, dim, generator=generator)
        target_log_var = -1.0 + 0.3 * torch.randn(num_target, dim, generator=generator)
    baseline = _peak_rss_mib()
    runs = []
    for _ in range(repeats if method != "public" else 1):
        start, cpu_start = time.perf_counter(), _cpu_seconds()
        retrieved = _select(method, prior, target, prior_log_var, target_log_var, fraction)
        runs.append((time.perf_counter() - start, _cpu_seconds() - cpu_start))
    seconds, cpu_seconds = min(runs)
    np.save(out, np.sort(retrieved))
    return {
        "seconds": seconds,
        "cpu_seconds": cpu_seconds,
        "extra_mib": _peak_rss_mib() - baseline,
        "threads": torch.get_num_threads(),
    }


def spawn(method: str, num_prior: int, num_target: int, dim: int, fraction: float, workdir: Path, repeats: int) -> dict:
    out = workdir / f"{method}_{num_prior}.npy"
    command = [sys.executable, __file__, "--child", method, str(num_prior), str(num_target), str(dim), str(fraction)]
    done = subprocess.run([*command, str(out), str(repeats)], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{method} at N={num_prior} failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["selection"] = out
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--num-target", type=int, default=2_500, help="M target latents (paper: 2,500)")
    parser.add_argument("--dim", type=int, default=64, help="latent dimension D (paper: 64)")
    parser.add_argument("--fraction", type=float, default=0.10, help="r, share retrieved (paper: 10%%)")
    parser.add_argument(
        "--sizes",
        type=int,
        nargs="*",
        default=[250_000, 2_300_000],
        help="prior sizes N for L2 (paper: 250k candidates; CALVIN's whole prior: 2.3M)",
    )
    parser.add_argument("--kl-sizes", type=int, nargs="*", default=[250_000], help="prior sizes N for the KL metric")
    parser.add_argument(
        "--public-sizes",
        type=int,
        nargs="*",
        default=[250_000],
        help="prior sizes N for the dense float64 cdist baseline (~5 GB at 250k); none: skip it",
    )
    parser.add_argument(
        "--cdist-sizes",
        type=int,
        nargs="*",
        help="prior sizes N for the chunked float32 torch.cdist baseline (default: the --sizes values); none: skip it",
    )
    parser.add_argument(
        "--cdist-chunk", type=int, default=CDIST_CHUNK, help=f"prior rows per cdist block (default {CDIST_CHUNK})"
    )
    parser.add_argument(
        "--repeats", type=int, default=3, help="runs per skillret row; the best time is printed (the machine is shared)"
    )
    parser.add_argument("--child", nargs=7, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        method, num_prior, num_target, dim, fraction, out, repeats = args.child
        result = run_method(method, int(num_prior), int(num_target), int(dim), float(fraction), Path(out), int(repeats))
        print(json.dumps(result))
        return

    import numpy as np

    plan = [("skillret-l2", n) for n in args.sizes] + [("skillret-kl", n) for n in args.kl_sizes]
    cdist = f"cdist-{args.cdist_chunk}"
    plan += [(cdist, n) for n in (args.sizes if args.cdist_sizes is None else args.cdist_sizes)]
    plan += [("public", n) for n in args.public_sizes]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for method, num_prior in plan:
            print(f"running {method} N={num_prior:,} ...", flush=True)
            result = spawn(method, num_prior, args.num_target, args.dim, args.fraction, Path(tmp), args.repeats)
            rows.append((method, num_prior, result))
        reference = {n: np.load(r["selection"]) for m, n, r in rows if m == "public"}
        print(
            f"\nM={args.num_target:,} target latents, D={args.dim}, r={args.fraction:.0%}, fp32 inputs, "
            f"{rows[0][2]['threads']} torch threads"
        )
        print(f"{'method':<34} {'N':>10} {'time s':>8} {'cpu s':>8} {'extra MiB':>10} {'same set as float64':>20}")
        for method, num_prior, result in rows:
            name = {
                "skillret-l2": "skillret L2 (chunked GEMM)",
                "skillret-kl": "skillret symmetric KL",
                cdist: f"chunked torch.cdist ({args.cdist_chunk} rows)",
                "public": "public: dense float64 cdist",
            }[method]
            same = "-"
            if num_prior in reference and method != "public":
                same = "yes" if np.array_equal(np.load(result["selection"]), reference[num_prior]) else "NO"
            elif method == "public":
                same = "(reference)"
            if method == "skillret-kl":
                same = "n/a (other metric)"
            print(
                f"{name:<34} {num_prior:>10,} {result['seconds']:>8.2f} {result['cpu_seconds']:>8.2f} "
                f"{result['extra_mib']:>10.0f} {same:>20}"
            )
        skillret_l2 = {n: r for m, n, r in rows if m == "skillret-l2"}
        for method, num_prior, result in rows:
            if method == cdist and num_prior in skillret_l2:
                mine = skillret_l2[num_prior]
                print(
                    f"cdist / skillret L2 at N={num_prior:,}: {result['seconds'] / mine['seconds']:.2f}x wall time, "
                    f"{result['cpu_seconds'] / mine['cpu_seconds']:.2f}x CPU time"
                )


if __name__ == "__main__":
    main()
