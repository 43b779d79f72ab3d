"""The TorchRL actor acts exactly like lerobot-eval: same saved policy, same observations -> identical actions.

A checkpoint folder is written the way lerobot-train writes `pretrained_model/` (policy + its processors), rolled
out for 30 steps in the kitchen through `torchrl.envs.GymEnv` with `LeRobotActor`, and the recorded observations are
then replayed through lerobot-eval's per-step chain (`rollout()` in lerobot/scripts/lerobot_eval.py) with a freshly
loaded policy. ACT is included because, unlike skillret, its processors really normalise (saved dataset stats).
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.envs.factory import make_env_pre_post_processors
from lerobot.envs.utils import preprocess_observation
from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors
from lerobot.utils.constants import ACTION
from policy_fixtures import tiny_config
from synthetic import make_synthetic_dataset

import lerobot_skillret  # noqa: F401  (registers the gym ids and the env/policy types)
from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.env_config import PandaKitchenEnv
from lerobot_skillret.kitchen.tasks import get_task
from lerobot_skillret.pipeline.torchrl_actor import LeRobotActor

TASK = "breakfast"
STEPS = 30
REPO = "test/kitchen_like"


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    """Synthetic data with the kitchen's observation sizes, only for the policies' shapes and stats."""
    root = tmp_path_factory.mktemp("data") / "kitchen_like"
    return make_synthetic_dataset(
        root, repo_id=REPO, num_episodes=2, state_dim=len(O.STATE_NAMES), env_dim=len(O.ENV_STATE_NAMES)
    )


@pytest.fixture(scope="module")
def kitchen_env():
    from torchrl.envs import GymEnv  # a pinned dependency: a broken install fails here, it is not skipped

    env = GymEnv(f"gym_panda_kitchen/{TASK}")
    yield env
    env.close()


def policy_config(kind: str) -> PreTrainedConfig:
    if kind == "skillret":
        return tiny_config()
    # ACT with a chunk shorter than the rollout, so chunk boundaries (re-planning) are crossed several times.
    return make_policy_config(
        "act",
        device="cpu",
        push_to_hub=False,
        chunk_size=8,
        n_action_steps=8,
        dim_model=32,
        n_heads=2,
        dim_feedforward=64,
        n_encoder_layers=1,
        use_vae=False,
        pretrained_backbone_weights=None,
    )


def save_checkpoint(kind: str, dataset_root: Path, folder: Path) -> Path:
    """Like lerobot-train's save_checkpoint: weights + config, then both processors, in one folder."""
    torch.manual_seed(0)
    meta = LeRobotDatasetMetadata(REPO, root=dataset_root)
    config = policy_config(kind)
    policy = make_policy(config, ds_meta=meta)
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=meta.stats)
    policy.save_pretrained(folder)
    preprocessor.save_pretrained(folder)
    postprocessor.save_pretrained(folder)
    return folder


def eval_chain_actions(checkpoint: Path, observations: dict[str, torch.Tensor]) -> torch.Tensor:
    """lerobot-eval's policy construction and per-step chain, fed the recorded observations one step at a time."""
    config = PreTrainedConfig.from_pretrained(checkpoint)
    config.pretrained_path = checkpoint
    config.device = "cpu"
    env_config = PandaKitchenEnv(task=TASK)
    policy = make_policy(cfg=config, env_cfg=env_config)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(
        policy_cfg=config,
        pretrained_path=str(checkpoint),
        preprocessor_overrides={
            "device_processor": {"device": "cpu"},
            "rename_observations_processor": {"rename_map": {}},
        },
    )
    env_preprocessor, env_postprocessor = make_env_pre_post_processors(env_cfg=env_config, policy_cfg=config)
    policy.reset()
    actions = []
    with torch.no_grad():
        for t in range(len(observations["agent_pos"])):
            # A one-env vector env hands over (1, D) numpy arrays.
            raw = {key: value[t : t + 1].numpy() for key, value in observations.items()}
            observation = preprocess_observation(raw)
            observation["task"] = [get_task(TASK).description]  # add_envs_task: the env's task_description
            observation = env_preprocessor(observation)
            observation = preprocessor(observation)
            with torch.inference_mode():
                action = policy.select_action(observation)
            action = postprocessor(action)
            action = env_postprocessor({ACTION: action})[ACTION]
            actions.append(action.to("cpu").numpy()[0])
    return torch.from_numpy(np.stack(actions))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["skillret", "act"])
def test_torchrl_actor_matches_lerobot_eval_chain(kind, dataset_root, kitchen_env, tmp_path):
    checkpoint = save_checkpoint(kind, dataset_root, tmp_path / "pretrained_model")
    actor = LeRobotActor.from_pretrained(
        checkpoint, task=get_task(TASK).description, obs_keys=["agent_pos", "environment_state"]
    )
    actor.reset()
    kitchen_env.set_seed(0)
    rollout = kitchen_env.rollout(STEPS, actor, auto_reset=True)

    assert rollout.batch_size == (STEPS,), "the episode ended early: the comparison needs all 30 steps"
    actions = rollout["action"]
    assert actions.shape == (STEPS, len(O.ACTION_NAMES)) and actions.dtype == torch.float32
    # The observations changed along the rollout, so the policy really was fed the env's states step by step.
    assert not torch.equal(rollout["agent_pos"][0], rollout["agent_pos"][-1])

    recorded = {key: rollout[key] for key in ("agent_pos", "environment_state")}
    expected = eval_chain_actions(checkpoint, recorded)
    torch.testing.assert_close(actions, expected, rtol=0, atol=0)
