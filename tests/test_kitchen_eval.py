"""`lerobot-eval --env.type=panda_kitchen` runs a (tiny, untrained) LeRobot policy on a kitchen task end to end."""

from __future__ import annotations

import json
import os
import sys
import warnings

import pytest
from lerobot.configs.types import FeatureType
from lerobot.envs.utils import env_to_policy_features
from policy_fixtures import unit_stats

from lerobot_skillret.kitchen.env_config import PandaKitchenEnv

pytestmark = pytest.mark.slow


def _tiny_act_checkpoint(path) -> None:
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.act.processor_act import make_act_pre_post_processors

    features = env_to_policy_features(PandaKitchenEnv(task="breakfast"))
    config = ACTConfig(
        input_features={k: f for k, f in features.items() if f.type is not FeatureType.ACTION},
        output_features={"action": features["action"]},
        dim_model=16,
        n_heads=2,
        dim_feedforward=32,
        n_encoder_layers=1,
        n_decoder_layers=1,
        use_vae=False,
        chunk_size=4,
        n_action_steps=4,
        pretrained_backbone_weights=None,
        device="cpu",
        push_to_hub=False,
    )
    pre, post = make_act_pre_post_processors(config, dataset_stats=unit_stats(features))
    ACTPolicy(config).save_pretrained(path)
    pre.save_pretrained(path)
    post.save_pretrained(path)


def test_lerobot_eval_writes_eval_info(tmp_path, monkeypatch):
    from lerobot.scripts import lerobot_eval

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("MUJOCO_GL", os.environ.get("MUJOCO_GL", "egl"))
    ckpt = tmp_path / "act"
    _tiny_act_checkpoint(ckpt)
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "lerobot-eval",
            f"--policy.path={ckpt}",
            "--env.type=panda_kitchen",
            "--env.task=breakfast",
            "--env.episode_length=6",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={tmp_path / 'eval'}",
        ],
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lerobot_eval.main()
    assert not [w for w in caught if "task_description" in str(w.message)], "env attributes hidden by a wrapper"
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and info["overall"]["pc_success"] == 0.0
    assert list((tmp_path / "eval" / "videos").rglob("*.mp4"))
