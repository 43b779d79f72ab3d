"""The results tables: mean +- std over seeds of each (method, task) cell's best checkpoint.

Two metrics: the seed's binary success rate, and subtask progress (mean over rollouts of the largest fraction of
the goals unmet at reset that were met), which still separates methods when every success rate is 0.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lerobot_skillret.files import read_json, write_atomic, write_text_atomic
from lerobot_skillret.pipeline.methods import METHODS

PUBLISHED_CELLS = "*/*/seed*/cell.json"  # results_dir layout: <method>/<task>/seed<s>/cell.json
HELDOUT_FILE = "heldout_error.json"  # beside a published cell: held-out imitation errors (`skillret-pipeline heldout`)
PUBLISHED_HELDOUT = f"*/*/seed*/{HELDOUT_FILE}"


def collect(folder: Path, pattern: str = PUBLISHED_CELLS) -> dict[tuple[str, str], list[dict]]:
    """Every cell summary under `folder` matching `pattern`, grouped by (method, task)."""
    return _grouped(folder, pattern, _check_cell)


def collect_heldout(folder: Path, pattern: str = PUBLISHED_HELDOUT) -> dict[tuple[str, str], list[dict]]:
    """Every held-out score under `folder` matching `pattern`, grouped by (method, task)."""
    return _grouped(folder, pattern, _check_heldout)


def _grouped(folder: Path, pattern: str, check: Callable[[dict], str | None]) -> dict[tuple[str, str], list[dict]]:
    """The records matching `pattern`, each refused with its field named when the tables could not read it (a
    hand-edited or foreign file would end in a numpy error, or a success of 750 %)."""
    records: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for path in sorted(folder.glob(pattern)):
        record = read_json(path)
        problem = f"holds {type(record).__name__}, not a record" if not isinstance(record, dict) else None
        for key in ("method", "task"):
            if problem is None and not isinstance(record.get(key), str):
                problem = f"`{key}` must be a name (got {record.get(key)!r})"
        problem = problem or check(record)
        if problem:
            raise ValueError(
                f"{path}: {problem}. The pipeline writes this file: restore it, or delete it and run the same "
                "`skillret-pipeline` command on the output_dir it came from."
            )
        records[(record["method"], record["task"])].append(record)
    return dict(records)


def _is_number(value: object, low: float, high: float = math.inf, nan: bool = False) -> bool:
    """`value` is a number in [low, high] (or NaN, where `nan`)."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return False
    return low <= value <= high or (nan and math.isnan(value))


def _check_cell(cell: dict) -> str | None:
    """What makes `cell` unreadable for the tables, if anything."""
    if not isinstance(cell.get("n_episodes"), int) or not _is_number(cell["n_episodes"], 1):
        return f"`n_episodes` must be an integer >= 1 (got {cell.get('n_episodes')!r})"
    for metric in METRICS:  # fractions; a cell from before subtask progress existed has no `subgoals`
        if (metric in cell or metric == "success") and not _is_number(cell.get(metric), 0, 1):
            return f"`{metric}` must be a fraction in [0, 1] (got {cell.get(metric)!r})"
    return None


def _check_heldout(score: dict) -> str | None:
    """What makes the held-out `score` unreadable for its table, if anything."""
    rows = score.get("checkpoints")
    fine = isinstance(rows, list) and rows and all(isinstance(r, dict) for r in rows)
    steps = fine and all(_is_number(r.get("step"), 0) for r in rows)
    # an error is NaN where a checkpoint diverged: a score to show, not a damaged file
    if not steps or not all(_is_number(r.get(k), 0, nan=True) for r in rows for k in ("policy", "oracle")):
        return "`checkpoints` must be a list of {step, policy, oracle} with numbers >= 0"
    if not isinstance(score.get("heldout_episodes"), int):
        return f"`heldout_episodes` must be an integer (got {score.get('heldout_episodes')!r})"
    return None


def _order(methods: set[str]) -> list[str]:
    return [m for m in METHODS if m in methods] + sorted(methods - set(METHODS))


METRICS = {
    "success": "Success rate (%)",
    "subgoals": "Subtask progress (% of the goals unmet at reset that were reached)",
}


def _scores(runs: list[dict], metric: str) -> np.ndarray:
    """Percent scores of the runs that recorded `metric` (cells from before subtask progress existed lack it)."""
    return 100.0 * np.array([r[metric] for r in runs if metric in r])


def _grid(
    groups: dict[tuple[str, str], list[dict]], entry: Callable[[list[dict]], tuple[str, float] | None], digits: int
) -> list[str]:
    """Markdown rows: methods (canonical order); columns: tasks and the average of their means (only when every task
    has an entry). `entry` turns a (method, task) group into its text and mean, or None when it has nothing."""
    methods = _order({m for m, _ in groups})
    tasks = sorted({t for _, t in groups})
    lines = ["| method | " + " | ".join(tasks) + " | average |", "|---" * (len(tasks) + 2) + "|"]
    for method in methods:
        row, means = [], []
        for task in tasks:
            found = entry(groups.get((method, task), []))
            if found is None:
                row.append("—")
                continue
            row.append(found[0])
            means.append(found[1])
        average = f"{np.mean(means):.{digits}f}" if len(means) == len(tasks) else "—"
        lines.append(f"| {method} | " + " | ".join(row) + f" | {average} |")
    return lines


def _spread(scores: np.ndarray) -> float:
    """The sample standard deviation over seeds (ddof=1): with 3 seeds the population one understates it by 18 %."""
    return float(scores.std(ddof=1))


def markdown_table(cells: dict[tuple[str, str], list[dict]], metric: str = "success") -> str:
    """Rows: methods; columns: tasks and their average; entries: metric % mean +- sample std (seeds); one seed
    has no spread to show, so it prints its score alone."""
    if not cells:
        return "_No finished cells yet._\n"

    def entry(runs: list[dict]) -> tuple[str, float] | None:
        scores = _scores(runs, metric)
        if not scores.size:
            return None
        spread = f" ± {_spread(scores):.1f}" if scores.size > 1 else ""
        return f"{scores.mean():.1f}{spread} ({scores.size})", scores.mean()

    lines = _grid(cells, entry, digits=1)
    n_eps = sorted({r["n_episodes"] for runs in cells.values() for r in runs})
    lines.append("")
    lines.append(
        f"{METRICS[metric]} of the best evaluated checkpoint per seed (highest success, ties to higher progress), "
        f"mean ± sample std over seeds (seed count in parentheses); {'/'.join(map(str, n_eps))} rollouts per checkpoint."
    )
    return "\n".join(lines) + "\n"


def heldout_table(scores: dict[tuple[str, str], list[dict]]) -> str:
    """Rows: methods; columns: tasks and their average; entries: the final checkpoint's held-out error of the
    policy's skills, mean over seeds, with the oracle skills' error in parentheses."""

    def entry(runs: list[dict]) -> tuple[str, float] | None:
        finals = [run["checkpoints"][-1] for run in runs]
        if not finals:
            return None
        policy = float(np.mean([f["policy"] for f in finals]))
        return f"{policy:.3f} ({np.mean([f['oracle'] for f in finals]):.3f})", policy

    lines = _grid(scores, entry, digits=3)
    runs = [run for group in scores.values() for run in group]
    steps = sorted({run["checkpoints"][-1]["step"] for run in runs})
    episodes = sorted({run["heldout_episodes"] for run in runs})
    seed_counts = sorted({len(group) for group in scores.values()})
    lines += [
        "",
        f"Held-out imitation error of the final checkpoint (step {'/'.join(map(str, steps))}), mean over "
        f"{'/'.join(map(str, seed_counts))} seeds; oracle skills' error in parentheses; "
        f"{'/'.join(map(str, episodes))} held-out demonstrations per task. Squared action error in the decoder's "
        "normalised units ([-1, 1] for MIN_MAX actions), summed over action dimensions, averaged over steps; "
        "lower is better.",
    ]
    return "\n".join(lines) + "\n"


def budget_table(cells: dict[tuple[str, str], list[dict]]) -> str:
    """Rows: methods; columns: tasks; entries: training epochs and wall minutes, mean over seeds (the average column
    is wall minutes). Cells from before loss curves were recorded show their minutes only."""

    def entry(runs: list[dict]) -> tuple[str, float] | None:
        minutes = [r["train_seconds"] / 60 for r in runs if r.get("train_seconds")]
        if not minutes:
            return None
        epochs = [r["train_epochs"] for r in runs if r.get("train_epochs")]
        text = f"{np.mean(epochs):.0f} ep, " if epochs else ""
        return f"{text}{np.mean(minutes):.0f} min", float(np.mean(minutes))

    lines = _grid(cells, entry, digits=0)
    lines += [
        "",
        "Training budget: lerobot-train epochs (steps x batch size / frames of the target demos; a skillret batch "
        "also carries retrieved windows) and wall minutes of training, mean over seeds; the average column is "
        "minutes. Not included: stage 1 on the prior (shared by the tasks of a seed), no_prior's own stage 1 on the "
        "task's demos (as long as the prior's: same steps and batch), act_ft's pre-training on the prior (shared).",
    ]
    return "\n".join(lines) + "\n"


def markdown_report(cells: dict[tuple[str, str], list[dict]], heldout: dict[tuple[str, str], list[dict]]) -> str:
    """Both rollout tables, success first (the seed's metric), the training budgets, the held-out errors where
    scored, then what each row's method is."""
    sections = [f"### {METRICS[m]}\n\n{markdown_table(cells, m)}" for m in METRICS]
    sections.append(f"### Training budget\n\n{budget_table(cells)}")
    if heldout:
        sections.append(f"### Held-out imitation error (skillret variants)\n\n{heldout_table(heldout)}")
    methods = _order({m for m, _ in cells} | {m for m, _ in heldout})
    legend = [f"- `{m}`: {METHODS[m].summary}" for m in methods if m in METHODS]
    if legend:
        sections.append("### Methods\n\n" + "\n".join(legend) + "\n")
    return "\n".join(sections)


def bar_plot(cells: dict[tuple[str, str], list[dict]], path: Path) -> None:
    """One panel per metric, stacked; bars are methods grouped by task, error bars the std over seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = _order({m for m, _ in cells})
    tasks = sorted({t for _, t in cells})
    width = 0.8 / max(1, len(methods))
    width_in = max(6.5, 2.0 + 0.3 * len(tasks) * max(1, len(methods)))  # room for the title and legend
    fig, axes = plt.subplots(len(METRICS), 1, figsize=(width_in, 3.0 * len(METRICS)), sharex=True)
    for ax, (metric, label) in zip(axes, METRICS.items(), strict=True):
        for i, method in enumerate(methods):
            means, stds = [], []
            for task in tasks:
                scores = _scores(cells.get((method, task), []), metric)
                means.append(scores.mean() if scores.size else np.nan)  # a missing cell draws no bar
                stds.append(_spread(scores) if scores.size > 1 else 0.0)
            xs = np.arange(len(tasks)) + (i - (len(methods) - 1) / 2) * width
            ax.bar(xs, means, width, yerr=stds, capsize=2, label=method)
        ax.set_xticks(np.arange(len(tasks)), tasks)
        ax.set_ylabel(label.split(" (")[0] + " (%)")  # the tables spell out what progress counts
        ax.set_ylim(0, 100)
    axes[0].legend(fontsize=7, ncols=4)
    fig.suptitle("Panda kitchen: best checkpoint per seed, mean ± sample std over seeds")
    fig.tight_layout()
    write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)


def loss_plot(cells: dict[tuple[str, str], list[dict]], path: Path) -> bool:
    """One panel per task: every run's training loss against epochs (log scale), one colour per method, so a
    reader sees which budgets reached a plateau. False (nothing written) when no cell recorded a curve."""
    curves = {key: [r["loss_curve"] for r in runs if r.get("loss_curve")] for key, runs in cells.items()}
    tasks = sorted({t for (_, t), found in curves.items() if found})
    if not tasks:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = _order({m for (m, _), found in curves.items() if found})
    fig, axes = plt.subplots(1, len(tasks), figsize=(max(6.5, 4.5 * len(tasks)), 3.5), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for colour, method in enumerate(methods):
            for seed, curve in enumerate(curves.get((method, task), [])):
                epochs, losses = np.array(curve).T
                ax.plot(epochs, losses, color=f"C{colour}", lw=1, label=method if seed == 0 else None)
        ax.set(title=task, xlabel="epochs (lerobot-train)", ylabel="training loss", yscale="log")
        ax.legend(fontsize=7)
    fig.suptitle("Training loss per run (each method's own loss: compare shapes, not levels)", fontsize=9)
    fig.tight_layout()
    write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)
    return True


def write_report(
    cells: dict[tuple[str, str], list[dict]], folder: Path, heldout: dict[tuple[str, str], list[dict]] | None = None
) -> str:
    """`results.md` (the tables), `results.png` and, where cells recorded them, `loss_curves.png` in `folder`;
    returns the markdown."""
    report = markdown_report(cells, heldout or {})
    write_text_atomic(folder / "results.md", report)
    bar_plot(cells, folder / "results.png")
    if not loss_plot(cells, folder / "loss_curves.png"):
        (folder / "loss_curves.png").unlink(missing_ok=True)  # no stale figure beside tables without curves
    return report
