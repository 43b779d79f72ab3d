"""The seed's evaluation protocol (C.3): a seed's score is its best evaluated checkpoint's success rate."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

from lerobot_skillret.files import read_json, staged_dir, write_json_atomic
from lerobot_skillret.pipeline.plan import Cell, Plan
from lerobot_skillret.pipeline.results import HELDOUT_FILE


def read_eval(eval_info: Path) -> dict[str, float | int]:
    """Success rate in [0, 1], mean subtask progress in [0, 1] and rollout count from an `eval_info.json` of
    lerobot-eval (or its published copy, `eval_step<k>.json`).

    Progress is lerobot-eval's `avg_max_reward`: the kitchen's reward is the fraction of the goals unmet at reset
    that are met.
    """
    overall = read_json(eval_info)["overall"]
    return {
        "success": float(overall["pc_success"]) / 100.0,
        "subgoals": float(overall["avg_max_reward"]),
        "n_episodes": int(overall["n_episodes"]),
    }


# lerobot-train's periodic log line: "step:2K smpl:64K ep:211 epch:7.04 loss:0.012 grdn:..." (steps are rounded)
_TRAIN_LOG_LINE = re.compile(r"\bepch:(?P<epoch>[0-9.]+)\b.*?\bloss:(?P<loss>[0-9.eE+-]+)")


def read_loss_curve(train_log: Path) -> list[list[float]]:
    """(epoch, mean training loss since the previous line) pairs from a lerobot-train log; [] without a log.

    Epochs are lerobot-train's: steps x batch size / frames of the dataset it was given (the target demos; a
    skillret batch also carries retrieved windows)."""
    if not train_log.is_file():
        return []
    found = (_TRAIN_LOG_LINE.search(line) for line in train_log.read_text(errors="replace").splitlines())
    return [[float(m["epoch"]), float(m["loss"])] for m in found if m]


def summarise_cell(
    plan: Plan,
    cell: Cell,
    train_seconds: float | None,
    eval_seconds: float,
    loss_curve: list[list[float]] | None = None,
) -> dict[str, Any]:
    """Collect every evaluated checkpoint of one run and pick the best by success, as the seed's protocol does.

    Ties (e.g. every checkpoint at 0%) go to the higher subtask progress, then to the later checkpoint. The training
    loss curve (`read_loss_curve`) is kept so that a reader can see whether the budget reached a plateau.
    """
    rows = [
        {"step": step, **read_eval(plan.eval_dir(cell, step) / "eval_info.json")} for step, _ in plan.checkpoints(cell)
    ]
    if not rows:
        raise RuntimeError(f"no evaluated checkpoint for {cell}; did training save any (save_freq)?")
    # rounded: equal scores summed in another order differ in the last bits, and must still tie
    best = max(rows, key=lambda r: (round(r["success"], 9), round(r["subgoals"], 9), r["step"]))
    return {
        "method": cell.method,
        "task": cell.task,
        "seed": cell.seed,
        "success": best["success"],
        "subgoals": best["subgoals"],
        "best_step": best["step"],
        "n_episodes": best["n_episodes"],
        "checkpoints": rows,
        "train_seconds": train_seconds,
        "train_epochs": loss_curve[-1][0] if loss_curve else None,
        "loss_curve": loss_curve or [],
        "eval_seconds": round(eval_seconds, 1),
        "output_dir": str(plan.root),
    }


def publish_cell(plan: Plan, cell: Cell, summary: dict[str, Any], results_dir: Path | None) -> None:
    """Write the cell summary; copy it, the raw eval JSONs, the retrieval report's summary (retrieval methods) and
    the held-out errors (if scored) into the results folder kept in the repository."""
    write_json_atomic(plan.cell_path(cell), summary)
    if results_dir is None:
        return
    with staged_dir(plan.published_dir(results_dir, cell)) as tmp:  # the folder appears whole or not at all
        tmp.mkdir()
        for row in summary["checkpoints"]:
            eval_info = plan.eval_dir(cell, row["step"]) / "eval_info.json"
            shutil.copyfile(eval_info, tmp / f"eval_step{row['step']}.json")
        retrieval_summary = plan.retrieval_summary(cell)
        if retrieval_summary is not None:
            shutil.copyfile(retrieval_summary, tmp / "retrieval_summary.json")
        if plan.heldout_path(cell).exists():  # scored before this (re-)publication
            shutil.copyfile(plan.heldout_path(cell), tmp / HELDOUT_FILE)  # bytes unchanged, as `publish_heldout`
        (tmp / "cell.json").write_text(json.dumps(summary, indent=2, sort_keys=True))
