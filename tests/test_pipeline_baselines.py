"""The ACT baseline trains through the pipeline's own stock `lerobot-train` command on low-dim data (no cameras).

The options come from the pipeline configs (`baselines.act` of configs/pipeline/smoke.yaml, else of benchmark.yaml),
so the test checks the options the pipeline really passes: they must be accepted by lerobot-train for ACT on state + environment-state
observations, and must reach the saved policy config.
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

CONFIGS = [
    Path(__file__).resolve().parents[1] / "configs" / "pipeline" / name for name in ("smoke.yaml", "benchmark.yaml")
]

# Used only while neither config has a `baselines.act` section; the same values as the baseline fragment handed to
# the pipeline configs (chunked ACT without image backbone, sized for a 2-core CPU).
ACT_FALLBACK = TrainSpec(
    steps=1000,
    batch_size=32,
    save_freq=500,
    num_workers=0,
    args={
        "policy.chunk_size": 20,
        "policy.n_action_steps": 10,
        "policy.dim_model": 128,
        "policy.n_heads": 4,
        "policy.dim_feedforward": 512,
        "policy.n_encoder_layers": 2,
        "policy.n_decoder_layers": 1,
        "policy.use_vae": True,
        "policy.n_vae_encoder_layers": 2,
        "policy.latent_dim": 32,
        "policy.pretrained_backbone_weights": None,
        "policy.optimizer_lr": 1e-4,
    },
)


def act_spec() -> TrainSpec:
    for path in CONFIGS:
        if path.is_file() and "act" in (baselines := PipelineConfig.from_yaml(path).baselines):
            return baselines["act"]
    return ACT_FALLBACK


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
