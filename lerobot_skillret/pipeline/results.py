"""The results table: mean +- std over seeds of each (method, task) cell's best-checkpoint success rate."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from lerobot_skillret.pipeline.config import METHODS


def collect(results_dir: Path) -> dict[tuple[str, str], list[dict]]:
    """Every `cell.json` under results_dir, grouped by (method, task)."""
    cells: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for path in sorted(results_dir.glob("*/*/seed*/cell.json")):
        cell = json.loads(path.read_text())
        cells[(cell["method"], cell["task"])].append(cell)
    return dict(cells)


def _order(methods: set[str]) -> list[str]:
    return [m for m in METHODS if m in methods] + sorted(methods - set(METHODS))


def markdown_table(cells: dict[tuple[str, str], list[dict]]) -> str:
    """Rows: methods; columns: tasks and their average; entries: success % mean +- std (population) [seeds]."""
    if not cells:
        return "_No finished cells yet._\n"
    methods = _order({m for m, _ in cells})
    tasks = sorted({t for _, t in cells})
    lines = ["| method | " + " | ".join(tasks) + " | average |", "|---" * (len(tasks) + 2) + "|"]
    for method in methods:
        row, means = [], []
        for task in tasks:
            runs = cells.get((method, task), [])
            if not runs:
                row.append("—")
                continue
            scores = 100.0 * np.array([r["success"] for r in runs])
            means.append(scores.mean())
            row.append(f"{scores.mean():.1f} ± {scores.std():.1f} ({len(runs)})")
        average = f"{np.mean(means):.1f}" if len(means) == len(tasks) else "—"
        lines.append(f"| {method} | " + " | ".join(row) + f" | {average} |")
    n_eps = sorted({r["n_episodes"] for runs in cells.values() for r in runs})
    lines.append("")
    lines.append(
        f"Success rate (%) of the best evaluated checkpoint per seed, mean ± std over seeds (seed count in "
        f"parentheses); {'/'.join(map(str, n_eps))} rollouts per checkpoint."
    )
    return "\n".join(lines) + "\n"


def bar_plot(cells: dict[tuple[str, str], list[dict]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = _order({m for m, _ in cells})
    tasks = sorted({t for _, t in cells})
    width = 0.8 / max(1, len(methods))
    fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(tasks) * max(1, len(methods)) * 0.35, 3.6))
    for i, method in enumerate(methods):
        means, stds = [], []
        for task in tasks:
            scores = 100.0 * np.array([r["success"] for r in cells.get((method, task), [])])
            means.append(scores.mean() if scores.size else 0.0)  # a missing cell draws no bar
            stds.append(scores.std() if scores.size else 0.0)
        xs = np.arange(len(tasks)) + (i - (len(methods) - 1) / 2) * width
        ax.bar(xs, means, width, yerr=stds, capsize=2, label=method)
    ax.set_xticks(np.arange(len(tasks)), tasks)
    ax.set_ylabel("success rate (%)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=7, ncols=2)
    ax.set_title("Panda kitchen: best checkpoint per seed, mean ± std")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    tmp.replace(path)
