"""No score is measured on an initial state that made training data or tuned the task ladder: the env seeds of the
benchmark's datasets, its evaluations and the ladder's calibration rollouts are disjoint (`kitchen.seeds`)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from lerobot_skillret.kitchen.collect import episode_jobs
from lerobot_skillret.pipeline.config import PipelineConfig
from lerobot_skillret.pipeline.plan import Cell, Plan

ROOT = Path(__file__).resolve().parents[1]
BENCHMARK = ROOT / "configs" / "pipeline" / "benchmark.yaml"
CALIBRATION_ROLLOUTS = 50  # the published calibration's (benchmarks/results/learnability)


def _learnability():
    spec = importlib.util.spec_from_file_location(
        "kitchen_learnability", ROOT / "benchmarks" / "kitchen_learnability.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _option(command: list[str], name: str) -> int:
    return int(next(arg.split("=", 1)[1] for arg in command if arg.startswith(f"--{name}=")))


def test_benchmark_evaluations_calibration_and_generated_data_use_disjoint_env_seeds(tmp_path: Path) -> None:
    cfg = PipelineConfig.from_args(BENCHMARK, [f"--output_dir={tmp_path}"])
    plan = Plan(cfg)
    evaluated = set()
    for seed in cfg.seeds:
        command = plan.eval_stage(Cell(cfg.methods[0], cfg.tasks[0], seed), 2000, tmp_path / "ckpt").command
        first = _option(command, "seed")  # lerobot-eval resets episode i from seed + i
        evaluated |= set(range(first, first + _option(command, "eval.n_episodes")))

    d, h = cfg.data, cfg.heldout
    jobs = episode_jobs("play", d.seed, d.play_episodes)
    for task in cfg.tasks:
        jobs += episode_jobs("demos", d.seed, d.demo_episodes, task=task)
        jobs += episode_jobs("demos", h.seed, h.episodes, task=task)
    generated = {job.seed for job in jobs}

    calibrated = set(_learnability().rollout_seeds(CALIBRATION_ROLLOUTS))

    assert evaluated and generated and calibrated
    assert not evaluated & generated, "benchmark evaluations start from initial states of generated training data"
    assert not evaluated & calibrated, "the benchmark evaluates on initial states the task ladder was calibrated on"
    assert not calibrated & generated, "calibration rolls out from initial states of generated training data"
