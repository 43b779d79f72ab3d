"""`skillret-pipeline`: the whole method on the kitchen benchmark, one resumable command.

    skillret-pipeline run --config configs/pipeline/demo.yaml      # generate -> skills -> retrieval -> policy -> eval
    skillret-pipeline heldout --config configs/pipeline/benchmark.yaml  # offline held-out error of trained cells
    skillret-pipeline table --results benchmarks/results/comparison # markdown table + bar plot from raw eval JSONs

Every stage runs a stock CLI (skillret-generate, lerobot-train, skillret-retrieve, lerobot-eval) as a subprocess.
Finished stages are skipped on re-run, so an interrupted run is continued by running the same command again.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import logging
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from lerobot_skillret.files import read_json
from lerobot_skillret.pipeline.config import PipelineConfig
from lerobot_skillret.pipeline.methods import METHODS
from lerobot_skillret.pipeline.plan import Cell, Plan
from lerobot_skillret.pipeline.protocol import publish_cell, read_loss_curve, summarise_cell
from lerobot_skillret.pipeline.results import collect, collect_heldout, write_report
from lerobot_skillret.pipeline.stages import Cancelled, Stage, StageRunner

log = logging.getLogger("skillret.pipeline")

PLUGIN = "lerobot_policy_skillret"  # the distribution and module through which LeRobot's CLIs find skillret


def check_plugin() -> None:
    """Refuse to start when `lerobot-train` / `lerobot-eval` could not find `--policy.type=skillret`: LeRobot imports
    installed `lerobot_policy_*` plugins only, so a checkout on PYTHONPATH or an editable install whose folder moved
    would otherwise fail at the first training stage, after the data stages, with LeRobot's list of policy types."""
    try:
        importlib.metadata.distribution(PLUGIN)
        found = importlib.util.find_spec(PLUGIN) is not None
    except importlib.metadata.PackageNotFoundError:
        found = False
    if not found:
        root = Path(__file__).resolve().parents[2]
        raise RuntimeError(
            f"the LeRobot plugin {PLUGIN} is not installed in this Python (or its editable install points at a "
            f"folder that is gone), so lerobot-train would not know --policy.type=skillret; "
            f"install the package: pip install -e {root}"
        )


def prerequisites(plan: Plan, cell: Cell) -> list[Stage]:
    """Stages shared between cells that `cell` needs first: stage-1 skills on the prior, a baseline's pre-training."""
    method = METHODS[cell.method]
    if method.skills == "prior":
        return [plan.skills_stage(cell.seed)]
    if method.pretrain_on_prior:
        return [plan.prior_pretraining_stage(cell.method, cell.seed)]
    return []


def training_stages(plan: Plan, cell: Cell) -> list[Stage]:
    """What `cell` trains, in order: shared prerequisites, its own skills and retrieval if any, its policy."""
    stages = prerequisites(plan, cell)
    method = METHODS[cell.method]
    if method.skills == "target":
        stages.append(plan.skills_stage(cell.seed, cell.task))
    if method.retrieval is not None:
        stages.append(plan.retrieval_stage(cell.task, cell.method, cell.seed))
    return [*stages, plan.train_stage(cell)]


def evaluation_stages(plan: Plan, cell: Cell) -> list[Stage]:
    """One `lerobot-eval` per saved checkpoint that the protocol evaluates (none before training has saved any)."""
    return [plan.eval_stage(cell, step, checkpoint) for step, checkpoint in plan.checkpoints(cell)]


def run_cell(plan: Plan, runner: StageRunner, cell: Cell, results_dir: Path | None) -> dict:
    training = training_stages(plan, cell)
    built = [*training, *evaluation_stages(plan, cell)]
    if plan.cell_path(cell).exists() and all(stage.done() for stage in built):
        # a summary stands for the stages it came from: after a config change they are refused, not re-reported;
        # one deleted (the fix the refusal names) is rebuilt below and the cell summarised again
        for stage in built:
            runner.check_built(stage)
        log.info("[skip] cell %s/%s/seed%d (summary exists)", cell.method, cell.task, cell.seed)
        summary = read_json(plan.cell_path(cell))
        if results_dir is not None and not plan.published_dir(results_dir, cell).exists():
            publish_cell(plan, cell, summary, results_dir)  # results_dir was added after the cell finished
        return summary
    for stage in training:
        runner.run(stage)  # skipped when built already; waits on its lock while another job builds it
    train = training[-1]
    start = time.monotonic()
    for stage in evaluation_stages(plan, cell):
        runner.run(stage)
    curve = read_loss_curve(runner.log_path(train))
    summary = summarise_cell(plan, cell, runner.timing(train.name), time.monotonic() - start, curve)
    publish_cell(plan, cell, summary, results_dir)
    log.info(
        "[cell] %s/%s/seed%d: success %.2f, subtask progress %.2f (best of %d checkpoints, step %d)",
        cell.method,
        cell.task,
        cell.seed,
        summary["success"],
        summary["subgoals"],
        len(summary["checkpoints"]),
        summary["best_step"],
    )
    return summary


def _runner(cfg: PipelineConfig, plan: Plan) -> StageRunner:
    env = {"HF_HUB_OFFLINE": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    runner = StageRunner(plan.root, env=env | ({"OMP_NUM_THREADS": str(cfg.threads)} if cfg.threads else {}))
    if threading.current_thread() is threading.main_thread():
        runner.stop_on_sigterm()
    return runner


def _results_dir(cfg: PipelineConfig) -> Path | None:
    return Path(cfg.results_dir).resolve() if cfg.results_dir else None


def _report(plan: Plan) -> str:
    """The tables of every finished cell of the output folder, including other processes' or other method lists'."""
    return write_report(
        collect(plan.root, Plan.CELL_SUMMARIES), plan.root, collect_heldout(plan.root, plan.heldout_scores())
    )


def run(cfg: PipelineConfig) -> Path:
    """Run (or continue) every stage of `cfg`; return the markdown table's path."""
    check_plugin()
    plan = Plan(cfg)
    runner = _runner(cfg, plan)
    start = time.monotonic()
    for stage in plan.data_stages():
        runner.run(stage)
    run_jobs(plan, runner, _results_dir(cfg), cfg.jobs)
    print(_report(plan))
    table_path = plan.root / "results.md"
    log.info("pipeline finished in %.1f min; table: %s", (time.monotonic() - start) / 60, table_path)
    return table_path


def heldout(cfg: PipelineConfig) -> None:
    """Score the trained skillret-variant cells of `cfg` on held-out demos; refresh the tables of the output folder
    and of `results_dir`."""
    from lerobot_skillret.pipeline.heldout import run_heldout  # the policy model: only this command needs it

    plan = Plan(cfg)
    results_dir = _results_dir(cfg)
    if results_dir is not None and not results_dir.is_dir():
        log.warning("results_dir %s does not exist: scores are kept in %s only", results_dir, plan.root)
    run_heldout(plan, _runner(cfg, plan), results_dir)
    print(_report(plan))
    if results_dir is not None and results_dir.is_dir():
        write_report(collect(results_dir), results_dir, collect_heldout(results_dir))
        log.info("tables refreshed: %s", results_dir / "results.md")


def run_jobs(plan: Plan, runner: StageRunner, results_dir: Path | None, jobs: int) -> None:
    """Shared stages first, then every cell, `jobs` at a time. Cells that need no shared stage (LeRobot baselines)
    are queued before the others, so with more jobs than shared stages they run while stage 1 trains.

    The first failure is logged at once and sets `runner.cancel`: no further stage starts, stages in flight finish,
    and the first error is raised. Ctrl-C or SIGTERM stops the stages in flight too.
    """
    cells = sorted(plan.cells(), key=lambda c: (c.seed, bool(prerequisites(plan, c))))
    shared = {stage.name: stage for cell in cells for stage in prerequisites(plan, cell)}

    def job(what: str, fn: Callable[..., object], *args: object) -> None:
        if runner.cancel.is_set():
            raise Cancelled(f"{what} not started")
        try:
            fn(*args)
        except Cancelled:
            raise
        except BaseException as err:
            log.error("[fail] %s: %s", what, str(err).splitlines()[0] if str(err) else type(err).__name__)
            runner.cancel.set()
            raise

    pool = ThreadPoolExecutor(max_workers=jobs)
    futures = [pool.submit(job, name, runner.run, stage) for name, stage in shared.items()]
    futures += [
        pool.submit(job, f"cell {c.method}/{c.task}/seed{c.seed}", run_cell, plan, runner, c, results_dir)
        for c in cells
    ]
    try:
        errors = [f.exception() for f in as_completed(futures)]
    except BaseException:  # Ctrl-C (SIGINT reaches the stages with the process group) or SIGTERM (`stop_on_sigterm`)
        runner.cancel.set()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    first = next((e for e in errors if e is not None and not isinstance(e, Cancelled)), None)
    if first is not None:
        raise first


def _log_to_stderr() -> None:
    """Our own handler: imported libraries may already have configured the root logger (basicConfig is a no-op)."""
    if not log.handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", datefmt="%H:%M:%S"))
        log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False


CONFIG_HELP = "pipeline YAML (see configs/pipeline/)"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="skillret-pipeline", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="run or continue the pipeline described by a config file")
    overrides = "then any config key as for lerobot-train: --eval.n_episodes=10 --tasks=[cook] --output_dir=out/x"
    run_p.add_argument("--config", "--config_path", dest="config", required=True, type=Path, help=CONFIG_HELP)
    run_p.epilog = overrides
    heldout_p = sub.add_parser(
        "heldout",
        help="score the trained skillret variants of a config on held-out demos (offline; generates them once)",
    )
    heldout_p.add_argument("--config", "--config_path", dest="config", required=True, type=Path, help=CONFIG_HELP)
    heldout_p.epilog = overrides
    table_p = sub.add_parser("table", help="markdown table + bar plot from a folder of finished cells")
    table_p.add_argument(
        "--results",
        type=Path,
        default=Path("benchmarks/results/comparison"),
        help="folder holding <method>/<task>/seed<s>/cell.json (default: benchmark.yaml's results_dir, %(default)s)",
    )
    args, rest = parser.parse_known_args(argv)
    if args.command == "table" and rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    bad = [item for item in rest if not item.startswith("--")]
    if bad:  # the pre-draccus form `eval.n_episodes=10`
        parser.error(f"overrides are written as for lerobot-train, e.g. --{bad[0]} (got {' '.join(bad)})")
    _log_to_stderr()
    if args.command in ("run", "heldout"):
        try:
            cfg = PipelineConfig.from_args(args.config, rest)
            (run if args.command == "run" else heldout)(cfg)
        except (FileNotFoundError, ValueError, RuntimeError) as err:
            parser.exit(2, f"skillret-pipeline: {err}\n")
        except KeyboardInterrupt:
            parser.exit(130, "skillret-pipeline: stopped; finished stages are kept: run the same command to go on\n")
    else:
        if not args.results.is_dir():
            parser.exit(2, f"skillret-pipeline: {args.results} does not exist: no finished cells yet.\n")
        try:
            cells, heldout_scores = collect(args.results), collect_heldout(args.results)
        except ValueError as err:  # a record cut short or edited by hand
            parser.exit(2, f"skillret-pipeline: {err}\n")
        if not cells:  # an empty table would replace the folder's results.md and plots
            hint = (
                "it is a run's output_dir, whose results.md every `skillret-pipeline run` rewrites; "
                if any(args.results.glob(Plan.CELL_SUMMARIES))
                else ""
            )
            parser.exit(
                2,
                f"skillret-pipeline: no <method>/<task>/seed<s>/cell.json under {args.results} ({hint}pass a "
                "results_dir, e.g. benchmarks/results/comparison); nothing written.\n",
            )
        print(write_report(cells, args.results, heldout_scores))


if __name__ == "__main__":
    main()
