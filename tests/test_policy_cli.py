"""Both training stages through the real `lerobot-train` CLI, then `lerobot-eval` on a toy env of this module."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from policy_fixtures import PRIOR_REPO, QUICK_TRAIN, TARGET_REPO, TINY_CLI, TRAIN_ENV, stage2_cli, write_retrieval
from safetensors.torch import load_file
from synthetic import make_synthetic_dataset

from lerobot_skillret.data.fingerprint import checkpoint_fingerprint
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

BIN = Path(sys.executable).parent
STATE_DIM, ENV_DIM, ACTION_DIM = 6, 5, 7


class ToyReachEnv(gym.Env):
    """Smooth random low-dim observations shaped like the synthetic datasets; success = action[0] > 0.5."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, episode_length: int = 12) -> None:
        self.observation_space = gym.spaces.Dict(
            {
                "agent_pos": gym.spaces.Box(-10, 10, (STATE_DIM,), np.float32),
                "environment_state": gym.spaces.Box(-10, 10, (ENV_DIM,), np.float32),
            }
        )
        self.action_space = gym.spaces.Box(-1, 1, (ACTION_DIM,), np.float32)
        self._max_episode_steps = episode_length
        self.task, self.task_description = "reach", "reach"
        self._t = 0

    def _observation(self) -> dict:
        t = self._t / 10.0
        return {
            "agent_pos": np.sin(t + np.arange(STATE_DIM)).astype(np.float32),
            "environment_state": np.cos(t + np.arange(ENV_DIM)).astype(np.float32),
        }

    def reset(self, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._t = 0
        return self._observation(), {"is_success": False}

    def step(self, action):
        self._t += 1
        success = bool(np.asarray(action)[0] > 0.5)
        truncated = self._t >= self._max_episode_steps
        return self._observation(), float(success), success, truncated, {"is_success": success}

    def render(self):
        return np.zeros((16, 16, 3), dtype=np.uint8)


@EnvConfig.register_subclass("skillret_toy")
@dataclass
class ToyEnvConfig(EnvConfig):
    task: str | None = "Reach-v0"
    fps: int = 20
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {
            "action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
            "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(ENV_DIM,)),
        }
    )
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            "action": "action",
            "agent_pos": "observation.state",
            "environment_state": "observation.environment_state",
        }
    )

    @property
    def gym_kwargs(self) -> dict:
        return {}


if "gym_skillret_toy/Reach-v0" not in gym.registry:
    gym.register("gym_skillret_toy/Reach-v0", entry_point=ToyReachEnv, order_enforce=False)


def lerobot_train(*args: str, base: Sequence[str] = QUICK_TRAIN) -> None:
    """Run lerobot-train with `base` (the quick CPU settings) then `args`; fail with its output's tail."""
    result = subprocess.run(
        [str(BIN / "lerobot-train"), *base, *args],
        env=TRAIN_ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-5000:]


@pytest.mark.slow
def test_two_stages_with_lerobot_train_then_lerobot_eval(tmp_path, monkeypatch):
    prior = make_synthetic_dataset(tmp_path / "prior", PRIOR_REPO, num_episodes=5, seed=0)
    target = make_synthetic_dataset(tmp_path / "target", TARGET_REPO, num_episodes=3, seed=1)

    # Stage 1 (Algorithm 1) on the prior dataset.
    lerobot_train(
        "--policy.stage=skills",
        f"--dataset.repo_id={PRIOR_REPO}",
        f"--dataset.root={prior}",
        f"--output_dir={tmp_path / 'stage1'}",
        *TINY_CLI,
    )
    stage1 = tmp_path / "stage1" / "checkpoints" / "last" / "pretrained_model"
    assert (stage1 / "model.safetensors").is_file()
    # lerobot-train took the policy's optimizer preset: Adam with torch's fused kernel
    optimizer = json.loads((stage1 / "train_config.json").read_text())["optimizer"]
    assert optimizer["type"] == "skillret_adam" and optimizer["fused"] is True

    # A retrieval file on that checkpoint (what skillret-retrieve writes), a few prior windows.
    retrieval = write_retrieval(tmp_path / "retrieval.safetensors", stage1, prior, target, [2, 11, 40, 63])

    # Stage 2 (Algorithm 2) on the target dataset, from the stage-1 checkpoint.
    lerobot_train(
        *stage2_cli(stage1, target, prior, retrieval, tmp_path / "stage2"),
        "--policy.fast_windows=false",  # stage 1 used cpu.json's fast windows; this covers LeRobot's own windows
        "--policy.use_amp=true",  # bf16 autocast (LeRobot's Accelerator) in training, and so in lerobot-eval below
    )
    stage2 = tmp_path / "stage2" / "checkpoints" / "last" / "pretrained_model"
    saved = json.loads((stage2 / "config.json").read_text())
    assert saved["stage"] == "policy" and saved["skills_checkpoint_fingerprint"] == checkpoint_fingerprint(stage1)
    assert saved["use_amp"]
    # the normalisation the skill model was trained with survives --policy.path on another dataset
    before, after = load_file(str(stage1 / "model.safetensors")), load_file(str(stage2 / "model.safetensors"))
    for name in [n for n in before if n.startswith("normalizer.")]:
        assert torch.equal(before[name], after[name]), name
    assert not torch.equal(before["latent_policy.head.0.weight"], after["latent_policy.head.0.weight"])

    # lerobot-eval on the toy env, in this process (the env type is registered by this module).
    from lerobot.scripts import lerobot_eval

    monkeypatch.setattr(
        sys,
        "argv",
        [
            "lerobot-eval",
            f"--policy.path={stage2}",
            "--env.type=skillret_toy",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={tmp_path / 'eval'}",
        ],
    )
    lerobot_eval.main()
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2 and 0.0 <= info["overall"]["pc_success"] <= 100.0


@pytest.mark.slow
def test_stage1_resumes_with_its_optimizer_state(tmp_path):
    """`--resume=true` re-parses the saved train config, whose optimizer is the plugin's `skillret_adam`, and
    reloads the fused Adam's state: the run goes on from its last step."""
    prior = make_synthetic_dataset(tmp_path / "prior", PRIOR_REPO, num_episodes=5, seed=0)
    out = tmp_path / "stage1"
    lerobot_train(
        "--policy.stage=skills",
        f"--dataset.repo_id={PRIOR_REPO}",
        f"--dataset.root={prior}",
        f"--output_dir={out}",
        *TINY_CLI,
    )
    config = out / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    lerobot_train(f"--config_path={config}", "--resume=true", "--steps=5", base=())
    assert (out / "checkpoints" / "000005" / "training_state" / "optimizer_state.safetensors").is_file()


@pytest.mark.slow
def test_lerobot_eval_on_the_kitchen_env(tmp_path, monkeypatch):
    """A skillret checkpoint shaped by the `panda_kitchen` env's features rolls out in the robosuite kitchen
    through lerobot-eval (toy scale: one short episode; the weights are untrained)."""
    from lerobot.envs.utils import env_to_policy_features
    from lerobot.scripts import lerobot_eval
    from policy_fixtures import tiny_config, unit_stats

    from lerobot_skillret.kitchen.env_config import PandaKitchenEnv
    from lerobot_skillret.policy.processor_skillret import make_skillret_pre_post_processors

    monkeypatch.setenv("MUJOCO_GL", os.environ.get("MUJOCO_GL", "egl"))
    features = env_to_policy_features(PandaKitchenEnv())
    config = tiny_config(stage="policy")
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    checkpoint = tmp_path / "pretrained_model"
    SkillRetPolicy(config, dataset_stats=unit_stats(features)).save_pretrained(checkpoint)
    for processor in make_skillret_pre_post_processors(config):
        processor.save_pretrained(checkpoint)
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "lerobot-eval",
            f"--policy.path={checkpoint}",
            "--env.type=panda_kitchen",
            "--env.episode_length=12",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={tmp_path / 'eval'}",
        ],
    )
    lerobot_eval.main()
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
