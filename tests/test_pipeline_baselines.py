"""The ACT and Diffusion baselines train through the pipeline's own stock `lerobot-train` command on low-dim data.

The options come from `baselines.<method>` of configs/pipeline/benchmark.yaml, so the test checks the options the
pipeline really passes: lerobot-train must accept them on state + environment-state observations (no cameras), the
policy's own dependencies must be installed (Diffusion needs `diffusers`, which lerobot only brings with its
`[diffusion]` extra), and the options must reach the saved policy config.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from synthetic import make_synthetic_dataset

from lerobot_skillret.pipeline.config import BaselineSpecs, PipelineConfig, TrainSpec
from lerobot_skillret.pipeline.plan import Cell, Plan
from lerobot_skillret.pipeline.stages import StageRunner

BENCHMARK = Path(__file__).resolve().parents[1] / "configs" / "pipeline" / "benchmark.yaml"


def baseline_spec(method: str) -> TrainSpec:
    """The options the benchmark really passes to a baseline (one source: the pipeline config)."""
    baselines = PipelineConfig.from_args(BENCHMARK).baselines
    assert method in baselines, f"{BENCHMARK} lost its `baselines.{method}` section"
    return baselines[method]


@pytest.mark.slow
@pytest.mark.parametrize("method", ["act", "diffusion"])
def test_baseline_trains_with_pipeline_options(tmp_path: Path, method: str) -> None:
    spec = dataclasses.replace(baseline_spec(method), steps=2, save_freq=2)
    cfg = PipelineConfig(
        output_dir=str(tmp_path / "run"),
        tasks=["breakfast"],
        methods=[method],
        baselines=BaselineSpecs(**{method: spec}),
    )
    plan = Plan(cfg)
    cell = Cell(method, "breakfast", 0)
    demos = plan.demos_root(cell.task)
    make_synthetic_dataset(demos, repo_id=plan.repo_id(demos), num_episodes=3, min_len=25, max_len=40)

    stage = plan.train_stage(cell)
    assert f"--policy.type={method}" in stage.command
    StageRunner(plan.root, env={"HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}).run(stage)

    checkpoints = plan.checkpoints(cell)
    assert [step for step, _ in checkpoints] == [2]
    pretrained = checkpoints[0][1]
    assert (pretrained / "model.safetensors").is_file()
    saved = json.loads((pretrained / "config.json").read_text())
    assert saved["type"] == method
    assert set(saved["input_features"]) == {"observation.state", "observation.environment_state"}
    for option, value in spec.args.items():
        if option.startswith("policy."):
            assert saved[option.removeprefix("policy.")] == value, option


def test_act_fine_tuned_gets_the_budget_of_act() -> None:
    """act_ft differs from act only by its initialisation (ACT pre-trained on the prior): the same steps, batch and
    evaluated checkpoints on the target demos, or the comparison measures the budget instead."""
    act, act_ft = baseline_spec("act"), baseline_spec("act_ft")
    budget = ("steps", "batch_size", "save_freq")
    assert [getattr(act_ft, f) for f in budget] == [getattr(act, f) for f in budget]
