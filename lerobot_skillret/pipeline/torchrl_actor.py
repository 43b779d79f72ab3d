"""Any saved LeRobot policy (skillret included) as a TorchRL actor, for `torchrl.envs.GymEnv` rollouts.

The actor applies exactly the per-step chain `lerobot-eval` applies (observation conversion, processors,
`select_action`, post-processor), so both paths produce the same actions for the same observations (`tests/test_pipeline_torchrl.py`). Two limits:
lerobot-eval's env-specific pre/post-processors are not applied (they are identities for `panda_kitchen`, not for
every env), and the caller must call `reset()` at each episode start (an auto-reset inside a torchrl rollout does
not reach the policy's observation history).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.envs.utils import preprocess_observation
from lerobot.policies.factory import get_policy_class, make_pre_post_processors
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase


class LeRobotActor(TensorDictModuleBase):
    """Reads the env's observation keys from a tensordict and writes `action` (unbatched or batched envs).

    `task` is the task's description (`get_task(name).description`), the string lerobot-eval hands a policy."""

    def __init__(self, policy: torch.nn.Module, preprocessor, postprocessor, task: str, obs_keys: list[str]) -> None:
        super().__init__()
        self.policy = policy
        self.preprocessor = preprocessor
        self.postprocessor = postprocessor
        self.task = task
        self.in_keys = obs_keys
        self.out_keys = ["action"]

    @classmethod
    def from_pretrained(cls, pretrained_path: str | Path, task: str, obs_keys: list[str]) -> LeRobotActor:
        """Load weights and the saved processors of a `pretrained_model/` folder (eval mode, CPU)."""
        path = Path(pretrained_path)
        if not (path / "config.json").is_file():
            raise FileNotFoundError(f"{path} holds no LeRobot checkpoint (config.json missing).")
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = "cpu"
        policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
        policy.eval()
        pre, post = make_pre_post_processors(
            cfg, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": "cpu"}}
        )
        return cls(policy, pre, post, task, obs_keys)

    def reset(self) -> None:
        """Call at the start of every episode (clears the policy's observation history and skill)."""
        self.policy.reset()

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        unbatched = td.batch_dims == 0
        raw = {key: _to_numpy(td.get(key), unbatched) for key in self.in_keys}
        observation = preprocess_observation(raw)
        observation["task"] = [self.task] * next(iter(observation.values())).shape[0]
        observation = self.preprocessor(observation)
        with torch.inference_mode():
            action = self.policy.select_action(observation)
        action = self.postprocessor(action).to("cpu", torch.float32)
        td.set("action", action[0] if unbatched else action)
        return td


def _to_numpy(value, unbatched: bool):
    """tensordict leaf or nested camera dict -> numpy with a leading batch dimension, as vector envs give."""
    if isinstance(value, TensorDictBase):
        return {k: _to_numpy(v, unbatched) for k, v in value.items()}
    array = value.cpu().numpy()
    return array[None] if unbatched else np.asarray(array)
