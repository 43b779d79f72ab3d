"""The ACT baseline trains through the pipeline's own stock `lerobot-train` command on low-dim data (no cameras).

The options come from `baselines.act` of configs/pipeline/benchmark.yaml, so the test checks the options the pipeline
really passes: lerobot-train must accept them for ACT on state + environment-state observations, and they must reach
the saved policy config.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from synthetic import make_synthetic_dataset

from lerobot_skillret.pipeline.config import PipelineConfig, TrainSpec
from lerobot_skillret.pipeline.plan import Cell, Plan
from lerobot_skillret.pipeline.stages import StageRunner

BENCHMARK = Path(__file__).resolve().parents[1] / "configs" / "pipeline" / "benchmark.yaml"


def act_spec() -> TrainSpec:
    """The ACT options the benchmark really passes (one source: the pipeline config)."""
    baselines = PipelineConfig.from_args(BENCHMARK).baselines
    assert "act" in baselines, f"{BENCHMARK} lost its `baselines.act` section"
    return baselines["act"]


@pytest.mark.slow
def test_act_baseline_trains_with_pipeline_options(tmp_path: Path) -> None:
    spec = dataclasses.replace(act_spec(), steps=2, save_freq=2)
    cfg = PipelineConfig(
        output_dir=str(tmp_path / "run"), tasks=["breakfast"], methods=["act"], baselines={"act": spec}
    )
    plan = Plan(cfg)
    cell = Cell("act", "breakfast", 0)
    demos = plan.demos_root(cell.task)
    make_synthetic_dataset(demos, repo_id=plan.repo_id(demos), num_episodes=3, min_len=25, max_len=40)

    stage = plan.train_stage(cell)
    assert "--policy.type=act" in stage.command
    StageRunner(plan.root, env={"HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}).run(stage)

    checkpoints = plan.checkpoints(cell)
    assert [step for step, _ in checkpoints] == [2]
    pretrained = checkpoints[0][1]
    assert (pretrained / "model.safetensors").is_file()
    saved = json.loads((pretrained / "config.json").read_text())
    assert saved["type"] == "act"
    assert set(saved["input_features"]) == {"observation.state", "observation.environment_state"}
    for option, value in spec.args.items():
        if option.startswith("policy."):
            assert saved[option.removeprefix("policy.")] == value, option
