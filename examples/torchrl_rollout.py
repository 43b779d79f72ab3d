"""Roll out any saved LeRobot policy (skillret, ACT, Diffusion, ...) in the kitchen through TorchRL.

`LeRobotActor` applies the per-step chain `lerobot-eval` applies (observation conversion, the checkpoint's saved
processors, `select_action`), so the actions equal lerobot-eval's (`tests/test_pipeline_torchrl.py`); the env is
`torchrl.envs.GymEnv("gym_panda_kitchen/<task>")`, so the rollout is a TensorDict ready for TorchRL tooling.

    MUJOCO_GL=egl python examples/torchrl_rollout.py \\
        --checkpoint outputs/demo/train/skillret/open_drawer/seed0/checkpoints/last/pretrained_model \\
        --task open_drawer --episodes 3
"""

import argparse
from pathlib import Path

import torch
from lerobot.configs.policies import PreTrainedConfig
from torchrl.envs import GymEnv

import lerobot_skillret  # noqa: F401  (registers the gym ids)
from lerobot_skillret.kitchen.seeds import EVAL_SEED0  # held-out initial states, as lerobot-eval's in the pipeline
from lerobot_skillret.kitchen.tasks import get_task
from lerobot_skillret.pipeline.torchrl_actor import LeRobotActor


def camera_options(checkpoint: Path) -> dict:
    """The env's cameras and image size, read from the checkpoint's image features (observation.images.<camera>)."""
    features = PreTrainedConfig.from_pretrained(checkpoint).input_features
    images = {key.rsplit(".", 1)[1]: feature.shape for key, feature in features.items() if ".images." in key}
    return {"cameras": tuple(images), "image_size": next(iter(images.values()))[-1]} if images else {}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True, type=Path, help="a `pretrained_model` folder")
    parser.add_argument("--task", required=True, help="kitchen task (e.g. open_drawer)")
    parser.add_argument("--episodes", type=int, default=3, help="rollouts (default 3)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    max_steps = get_task(args.task).max_steps
    cameras = camera_options(args.checkpoint)
    env = GymEnv(f"gym_panda_kitchen/{args.task}", **cameras)
    obs_keys = ["agent_pos", "environment_state", *(["pixels"] if cameras else [])]
    # the policy sees the task's description, as lerobot-eval gives it (language-conditioned policies read it)
    actor = LeRobotActor.from_pretrained(args.checkpoint, get_task(args.task).description, obs_keys)
    successes = 0
    for episode in range(args.episodes):
        initial = env.reset(seed=EVAL_SEED0 + episode)  # the initial state lerobot-eval's seed gives
        actor.reset()  # the policy's observation history starts afresh with each episode
        rollout = env.rollout(max_steps, actor, auto_reset=False, tensordict=initial, break_when_any_done=True)
        success = bool(rollout["next", "terminated"].any())  # a kitchen episode terminates only on success
        progress = float(rollout["next", "reward"].max())
        successes += success
        print(f"episode {episode}: {rollout.batch_size[0]} steps, success={success}, progress={progress:.2f}")
    env.close()
    print(f"success {successes}/{args.episodes}")


if __name__ == "__main__":
    main()
