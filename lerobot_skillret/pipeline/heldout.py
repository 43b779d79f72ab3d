"""Held-out imitation error: an offline score of the skillret variants' stage-2 checkpoints.

Ten rollouts per checkpoint move success in steps of 10 points, too coarse to order the variants. Scored instead on
demonstrations that no run trained on (another generation seed): at every window where a rollout would pick a skill
(every H steps), the latent policy picks one from the F observations before it and the closed-loop decoder runs it
along the demonstration's own observations (`SkillRetPolicy.imitation_error`). The oracle skill (the checkpoint's
encoder on the window itself) gives the floor that the decoder allows; another window's oracle skill (`shuffled`)
shows how much the decoder needs the skill at all.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import torch

from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler
from lerobot_skillret.files import read_json, write_json_atomic, write_text_atomic
from lerobot_skillret.pipeline.methods import METHODS
from lerobot_skillret.pipeline.plan import Cell, Plan
from lerobot_skillret.pipeline.results import HELDOUT_FILE
from lerobot_skillret.pipeline.stages import StageRunner
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

log = logging.getLogger("skillret.pipeline")


def skill_starts(columns: EpisodeColumns, horizon: int) -> torch.Tensor:
    """Global frame indices where a rollout would query the policy: every H steps from each episode's start."""
    start = columns.td["episode_start"].as_subclass(torch.Tensor)
    frames = torch.arange(len(columns))
    return frames[(frames - start) % horizon == 0]


@torch.no_grad()
def imitation_errors(checkpoint: Path, columns: EpisodeColumns) -> dict[str, float]:
    """Mean per-window action error of a stage-2 checkpoint's skills (`policy`), of the oracle's (`oracle`) and of
    other windows' oracle skills (`shuffled`)."""
    policy = SkillRetPolicy.from_pretrained(checkpoint).eval()
    config = policy.config
    if config.stage != "policy":
        raise ValueError(f"{checkpoint} is a stage-1 (skills) checkpoint; score stage-2 (policy) checkpoints.")
    sampler = WindowSampler(columns, config.history, config.horizon, keys=[*policy.low_dim_keys, "action"])
    errors = policy.imitation_error(sampler.gather(skill_starts(columns, config.horizon)))
    return {name: float(value.mean()) for name, value in errors.items()}


def score_cell(plan: Plan, cell: Cell, columns: EpisodeColumns) -> dict[str, Any]:
    """The held-out errors of every checkpoint the protocol evaluates for `cell` (the latest `max_checkpoints`)."""
    rows = [{"step": step, **imitation_errors(ckpt, columns)} for step, ckpt in plan.checkpoints(cell)]
    return {
        "method": cell.method,
        "task": cell.task,
        "seed": cell.seed,
        "heldout_episodes": plan.cfg.heldout.episodes,
        "heldout_seed": plan.cfg.heldout.seed,
        "frames": len(columns),
        "checkpoints": rows,
    }


def _is_current(path: Path, steps: list[int]) -> bool:
    """A stored score counts only if it covers the checkpoints the protocol evaluates now."""
    return path.exists() and [r["step"] for r in read_json(path)["checkpoints"]] == steps


def publish_heldout(plan: Plan, cell: Cell, results_dir: Path) -> None:
    """Copy `cell`'s score next to its published eval JSONs, if those came from this output folder."""
    published = plan.published_dir(results_dir, cell)
    summary = published / "cell.json"
    if summary.is_file() and read_json(summary).get("output_dir") == str(plan.root):
        write_text_atomic(published / HELDOUT_FILE, plan.heldout_path(cell).read_text())


def run_heldout(plan: Plan, runner: StageRunner, results_dir: Path | None) -> None:
    """Generate each task's held-out demos (a skippable stage) and score every trained skillret-variant cell.

    Cells whose stage-2 run has not finished are left out; a stored score is reused while it covers the checkpoints
    the protocol evaluates. Scores are copied next to the cells' published eval JSONs in `results_dir`."""
    cfg = plan.cfg
    if not any(METHODS[m].is_skillret for m in cfg.methods):
        raise ValueError(
            f"the config's methods {cfg.methods} hold no skillret variant to score (LeRobot baselines only)."
        )
    trained = [c for c in plan.cells() if METHODS[c.method].is_skillret and plan.train_dir(c).is_dir()]
    if not trained:  # a mistyped --output_dir or a config of another run: say so rather than exit 0 with no score
        raise ValueError(
            f"no trained skillret-variant cell in {plan.root} (methods {cfg.methods}, tasks {cfg.tasks}, seeds "
            f"{cfg.seeds}): pass the config and --output_dir of a `skillret-pipeline run` that trained them."
        )
    for task in cfg.tasks:
        columns = None  # loaded only if a cell of the task needs scoring
        for cell in (c for c in trained if c.task == task):
            path, steps = plan.heldout_path(cell), [step for step, _ in plan.checkpoints(cell)]
            if not steps:
                log.warning("[held-out] %s/%s/seed%d has no checkpoint: skipped", cell.method, task, cell.seed)
                continue
            if not _is_current(path, steps):
                if columns is None:
                    runner.run(plan.heldout_stage(task))
                    root = plan.heldout_root(task)
                    columns = EpisodeColumns.from_dataset(plan.repo_id(root), root)
                write_json_atomic(path, score_cell(plan, cell, columns))
                log.info("[held-out] %s/%s/seed%d scored", cell.method, task, cell.seed)
            if results_dir is not None:
                publish_heldout(plan, cell, results_dir)
