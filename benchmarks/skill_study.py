"""Do the stage-1 skills execute the target tasks? Oracle-skill success on the task ladder, against stage-1 training
steps and the size of the prior (play) data.

The method can only beat target-only imitation if its skill decoder, handed the right latent, does what the target
demonstrations did. This script measures that:
1. play data (`skillret-generate play`, --play-episodes of 1,000 steps; skipped when it exists) and its frames per
   primitive;
2. per prior size k in --prior-episodes: stage 1 (`lerobot-train`, configs/policy/cpu.json) on the first k play
   episodes, saving a checkpoint every --save-every steps;
3. per task: held-out demonstrations (`skillret-generate demos --seed 1`, seeds no training set uses);
4. per checkpoint and task: oracle-skill success on --episodes held-out demonstrations, the fraction of sub-goals
   met, and the teacher-forced oracle action error on all of them (`lerobot_skillret.pipeline.oracle`).

Every finished piece is kept: one JSON per (prior size, step, task) in --results (benchmarks/results/skills_contacts/;
skills/ holds the study on the kitchen before 2026-12-05's contact fix), a training run in --work
(outputs/skill_study/; a run killed half-way is redone from scratch). A re-run skips what exists: an added task is
only scored; a longer run (--steps 25000 --prior-episodes 160) trains anew (the learning rate is constant, so its
early checkpoints match the shorter run's) and scores only its new checkpoints.

    MUJOCO_GL=egl python benchmarks/skill_study.py                       # the default study (~1 h on 2 cores)
    MUJOCO_GL=egl python benchmarks/skill_study.py --prior-episodes 48 --tasks light_on --steps 3000
    python benchmarks/skill_study.py --table                             # table and plot of stored results
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import torch

from lerobot_skillret.files import write_json_atomic, write_text_atomic
from lerobot_skillret.kitchen.tasks import BUILT_IN, TASKS

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "skills_contacts"  # skills/: the same study before the contact fix
BIN = Path(sys.executable).parent
CONFIG = ROOT / "configs" / "policy" / "cpu.json"
PLAY_STEPS = 1000  # steps per play episode
BATCH_SIZE = json.loads(CONFIG.read_text())["batch_size"]  # stage 1's, as the config trains it
HELDOUT_SEED = 1  # demos seeds 1 * 1_000_003 + i: no training dataset here uses them (training demos use seed 0)


def run(cmd: list[str], log: Path) -> None:
    """Run `cmd` with its output in `log`; on failure show the log's tail."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as out:
        # one thread: torch's OpenMP threads spin-wait, and on a shared 2-core machine two of them ran stage 1
        # 10-30x slower (1.5 s per step instead of 0.05-0.15 s)
        env = {**os.environ, "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"}
        done = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, env=env)
    if done.returncode != 0:
        tail = log.read_text()[-3000:]
        raise SystemExit(f"failed ({done.returncode}): {' '.join(cmd)}\n--- {log} ---\n{tail}")


def play_data(work: Path, episodes: int) -> Path:
    root = work / f"play_n{episodes}"
    if not (root / "meta" / "kitchen.json").is_file():
        print(f"generating {episodes} play episodes -> {root}", flush=True)
        cmd = [str(BIN / "skillret-generate"), "play", "--root", str(root), "--episodes", str(episodes)]
        run([*cmd, "--steps-per-episode", str(PLAY_STEPS), "--overwrite"], work / "logs" / f"{root.name}.log")
    return root


def heldout_demos(work: Path, task: str, episodes: int) -> Path:
    root = work / f"heldout_{task}_n{episodes}"
    if not (root / "meta" / "kitchen.json").is_file():
        print(f"generating {episodes} held-out {task} demos -> {root}", flush=True)
        cmd = [str(BIN / "skillret-generate"), "demos", "--task", task, "--root", str(root), "--overwrite"]
        run([*cmd, "--seed", str(HELDOUT_SEED), "--episodes", str(episodes)], work / "logs" / f"{root.name}.log")
    return root


def train_skills(work: Path, play: Path, prior_episodes: int, steps: int, save_every: int) -> tuple[Path, float]:
    """Stage 1 on the first `prior_episodes` play episodes; returns the run folder and its wall time (s)."""
    out = work / "train" / f"prior{prior_episodes}_steps{steps}"
    timing = out / "wall_time.json"
    if timing.is_file():
        return out, json.loads(timing.read_text())["seconds"]
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)  # left by a killed run: lerobot-train refuses an existing folder
    print(f"stage 1 on {prior_episodes} play episodes, {steps} steps -> {out}", flush=True)
    start = time.monotonic()
    run(
        [
            str(BIN / "lerobot-train"),
            f"--config_path={CONFIG}",
            f"--dataset.repo_id=local/{play.name}",
            f"--dataset.root={play}",
            f"--dataset.episodes={list(range(prior_episodes))}",
            f"--output_dir={partial}",
            f"--steps={steps}",
            f"--save_freq={save_every}",
            "--num_workers=0",
            "--wandb.enable=false",
        ],
        work / "logs" / f"{out.name}.log",
    )
    seconds = time.monotonic() - start
    shutil.rmtree(out, ignore_errors=True)
    os.replace(partial, out)
    write_json_atomic(timing, {"seconds": round(seconds, 1)})
    return out, seconds


def checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    found = [(int(p.name), p / "pretrained_model") for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit()]
    return sorted(found)


def evaluate(args: argparse.Namespace) -> None:
    from lerobot_skillret.pipeline.oracle import oracle_success

    torch.set_num_threads(1)
    work = args.work.resolve()
    play = play_data(work, args.play_episodes)
    frames = json.loads((play / "meta" / "kitchen.json").read_text()).get("primitive_frames", {})
    results = args.results
    write_json_atomic(results / "play_primitive_frames.json", {"play": play.name, "frames": frames})
    print(f"play frames per primitive: {frames}", flush=True)
    demos = {task: heldout_demos(work, task, args.episodes) for task in args.tasks}
    for prior in args.prior_episodes:
        run_dir, seconds = train_skills(work, play, prior, args.steps, args.save_every)
        for step, ckpt in checkpoints(run_dir):
            for task in args.tasks:
                out = results / f"prior{prior}_step{step}_{task}.json"
                if out.is_file():
                    continue
                print(f"oracle skills: prior {prior} episodes, step {step}, {task}", flush=True)
                start = time.monotonic()
                result = oracle_success(
                    ckpt, demos[task], task, args.episodes, log=lambda line: print(line, flush=True)
                )
                result.update(
                    task=task,
                    level=TASKS[task].level,
                    prior_episodes=prior,
                    prior_frames=prior * PLAY_STEPS,
                    step=step,
                    batch_size=BATCH_SIZE,
                    train_wall_s=seconds,
                    eval_wall_s=round(time.monotonic() - start, 1),
                    heldout_seed=HELDOUT_SEED,
                )
                write_json_atomic(out, result)
                print(f"  -> success {result['success']:.0%}, goals {result['goals_met']:.0%}", flush=True)
    table(results)


def table(results: Path) -> None:
    """results.md (one row per prior size and step, one column per task, mean per level) and skills.png."""
    rows = [json.loads(p.read_text()) for p in sorted(results.glob("prior*_step*_*.json"))]
    if not rows:
        raise SystemExit(f"no results in {results}; run the study first")
    tasks = sorted({r["task"] for r in rows}, key=lambda t: (TASKS[t].level, t))
    keys = sorted({(r["prior_episodes"], r["step"]) for r in rows})
    cell = {(r["prior_episodes"], r["step"], r["task"]): r for r in rows}
    levels = sorted({TASKS[t].level for t in tasks})
    lines = [
        "# Oracle-skill success of stage-1 checkpoints on held-out demonstrations",
        "",
        "Success (sub-goals met) over held-out demos executed with their own encoder latents; last column: mean "
        "teacher-forced oracle action error. Written by `benchmarks/skill_study.py`.",
        "",
        "| prior frames | step | "
        + " | ".join(tasks)
        + " | "
        + " | ".join(f"level {lv}" for lv in levels)
        + " | error |",
        "|---" * (3 + len(tasks) + len(levels)) + "|",
    ]
    for prior, step in keys:
        got = [cell.get((prior, step, t)) for t in tasks]
        parts = [f"{r['success']:.0%} ({r['goals_met']:.0%})" if r else "" for r in got]
        for lv in levels:
            mine = [r["success"] for r, t in zip(got, tasks, strict=True) if r and TASKS[t].level == lv]
            parts.append(f"{sum(mine) / len(mine):.0%}" if mine else "")
        errors = [r["oracle_action_error"] for r in got if r]
        lines.append(
            f"| {prior * PLAY_STEPS:,} | {step:,} | " + " | ".join(parts) + f" | {sum(errors) / len(errors):.3f} |"
        )
    frames = results / "play_primitive_frames.json"
    if frames.is_file():
        counts = json.loads(frames.read_text())["frames"]
        total = max(sum(counts.values()), 1)
        lines += [
            "",
            "Play frames per primitive: " + ", ".join(f"{k} {v:,} ({v / total:.0%})" for k, v in counts.items()),
        ]
    write_text_atomic(results / "results.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    _plot(rows, tasks, results)


def _plot(rows: list[dict], tasks: list[str], results: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    priors = sorted({r["prior_episodes"] for r in rows})
    fig, axes = plt.subplots(1, len(priors), figsize=(4.5 * len(priors) + 2, 3.6), squeeze=False, sharey=True)
    colors = plt.get_cmap("tab20").colors  # one colour per task (the default cycle repeats after 10)
    dashes = {1: "-", 2: "--"}  # level 3 and longer dotted
    for ax, prior in zip(axes[0], priors, strict=True):
        for index, task in enumerate(tasks):
            mine = sorted(
                (r["step"], r["goals_met"]) for r in rows if r["prior_episodes"] == prior and r["task"] == task
            )
            if mine:
                steps, goals = zip(*mine, strict=True)
                level = TASKS[task].level
                style = {"color": colors[index % len(colors)], "linestyle": dashes.get(level, ":"), "marker": "o"}
                ax.plot(steps, [100 * g for g in goals], label=f"{task} (L{level})", **style)
        ax.set(title=f"prior {prior * PLAY_STEPS:,} frames", xlabel="stage-1 steps", ylim=(-5, 105))
    # sub-goals met: equal to success on a single step, and still informative where no chain completes
    axes[0][0].set_ylabel("oracle skills: sub-goals met (%)")
    axes[0][-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.tight_layout()
    tmp = results / "skills.png.tmp"
    fig.savefig(tmp, format="png", dpi=110)
    os.replace(tmp, results / "skills.png")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    short = [task.name for task in BUILT_IN if task.level <= 3]  # the ladder and the 3-step tasks
    parser.add_argument("--tasks", nargs="+", default=short, choices=sorted(TASKS), help="tasks to score")
    parser.add_argument(
        "--play-episodes", type=int, default=160, help=f"play episodes of {PLAY_STEPS} steps (default 160)"
    )
    parser.add_argument("--prior-episodes", type=int, nargs="+", default=[160, 32], help="prior sizes to train on")
    parser.add_argument("--steps", type=int, default=12500, help="stage-1 steps per run (default 12500)")
    parser.add_argument("--save-every", type=int, default=6250, help="checkpoint period (default 6250)")
    parser.add_argument("--episodes", type=int, default=10, help="held-out demos per task (default 10)")
    parser.add_argument("--work", type=Path, default=ROOT / "outputs" / "skill_study", help="data and runs")
    parser.add_argument(
        "--results",
        type=Path,
        default=RESULTS,
        help=f"one JSON per (prior, step, task), table, plot (default {RESULTS})",
    )
    parser.add_argument(
        "--table", action="store_true", help="no training: rebuild results.md and skills.png from the stored results"
    )
    args = parser.parse_args()
    if args.table:
        table(args.results)
        return
    if max(args.prior_episodes) > args.play_episodes:
        parser.error(f"--prior-episodes {max(args.prior_episodes)} > --play-episodes {args.play_episodes}")
    evaluate(args)


if __name__ == "__main__":
    main()
