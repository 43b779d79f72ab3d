"""Does the offline held-out imitation error predict rollout progress? Per task, the Spearman rank correlation over
every scored checkpoint (skillret variants x seeds x evaluated steps) between the policy's held-out error and the
subtask progress of that checkpoint's `lerobot-eval` rollouts, with a permutation p-value.

    skillret-pipeline heldout --config configs/pipeline/benchmark.yaml   # scores, published beside each cell
    python benchmarks/heldout_vs_rollouts.py --results benchmarks/results/benchmark [--exclude no_prior]

If the offline error tracked rollouts, rho would be clearly negative (lower error, more progress).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from lerobot_skillret.pipeline.protocol import read_eval
from lerobot_skillret.pipeline.results import PUBLISHED_HELDOUT


def ranks(values: np.ndarray) -> np.ndarray:
    """Ranks with ties sharing their average rank (progress takes few distinct values over 10 rollouts)."""
    order = values.argsort(kind="stable")
    ranked = np.empty(len(values))
    ranked[order] = np.arange(len(values), dtype=float)
    for value in np.unique(values):
        tied = values == value
        ranked[tied] = ranked[tied].mean()
    return ranked


def spearman(x: np.ndarray, y: np.ndarray, permutations: int, rng: np.random.Generator) -> tuple[float, float]:
    """Rank correlation and the two-sided share of label permutations at least as extreme."""
    rx, ry = ranks(x), ranks(y)
    rho = float(np.corrcoef(rx, ry)[0, 1])
    null = np.array([np.corrcoef(rx, rng.permutation(ry))[0, 1] for _ in range(permutations)])
    return rho, float((np.abs(null) >= abs(rho)).mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=Path, default=Path("benchmarks/results/benchmark"), help="published cells")
    parser.add_argument("--permutations", type=int, default=10_000, help="for the p-value")
    parser.add_argument("--exclude", nargs="*", default=[], help="methods to leave out, e.g. no_prior")
    args = parser.parse_args()
    pairs: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for path in sorted(args.results.glob(PUBLISHED_HELDOUT)):
        scores = json.loads(path.read_text())
        if scores["method"] in args.exclude:
            continue
        for row in scores["checkpoints"]:
            progress = read_eval(path.parent / f"eval_step{row['step']}.json")["subgoals"]
            pairs[scores["task"]].append((row["policy"], progress))
    if not pairs:
        raise SystemExit(f"no {PUBLISHED_HELDOUT} under {args.results}: run `skillret-pipeline heldout` first.")
    rng = np.random.default_rng(0)
    print(f"{'task':<12} {'checkpoints':>11} {'spearman rho':>12} {'p':>6}")
    for task, rows in sorted(pairs.items()):
        error, progress = np.array(rows).T
        rho, p = spearman(error, progress, args.permutations, rng)
        print(f"{task:<12} {len(rows):>11} {rho:>12.2f} {p:>6.3f}")


if __name__ == "__main__":
    main()
