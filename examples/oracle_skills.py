"""Can the skill decoder execute a task's demonstrations when it is handed the right skills?

Restores each demonstration's initial state in the kitchen env and, every H steps, encodes the demonstration's own
window at that time (the oracle latent) and lets the closed-loop decoder execute it. High success here and low
success of the trained policy points at the latent policy; low success here points at the skill model.

    MUJOCO_GL=egl python examples/oracle_skills.py \\
        --checkpoint outputs/demo/train/skillret/breakfast/seed0/checkpoints/last/pretrained_model \\
        --demos outputs/demo/data/demos_breakfast --task breakfast --episodes 5
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from lerobot.envs.utils import preprocess_observation

from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler
from lerobot_skillret.kitchen.gym_env import KitchenEnv
from lerobot_skillret.kitchen.observations import load_kitchen_meta
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy


def run_episode(
    policy: SkillRetPolicy,
    env: KitchenEnv,
    sampler: WindowSampler,
    first: int,
    length: int,
    initial_state: np.ndarray,
    slack: float,
) -> tuple[bool, list[str]]:
    """Oracle-skill rollout of one demonstration; returns (success, goals still unmet)."""
    env.reset(seed=0)
    env.scene.reset()
    env.scene.set_sim_state(initial_state)
    observation, horizon = env._obs(), policy.config.horizon
    policy.reset()
    for t in range(int(length * slack)):
        batch = preprocess_observation({key: value[None] for key, value in observation.items()})
        if t % horizon == 0:
            anchor = torch.tensor([first + min(t, length - 1)])
            policy.execute_skill(policy.encode_skill(sampler.gather(anchor))[0])
        action = policy.select_action(batch)[0].numpy()
        observation, _, _, _, info = env.step(action)
        if info["is_success"]:
            return True, []
    return False, env._task.unmet(env.scene)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True, type=Path, help="a skillret `pretrained_model` folder")
    parser.add_argument("--demos", required=True, type=Path, help="a demos dataset made by `skillret-generate demos`")
    parser.add_argument("--task", required=True, help="the demos' task (e.g. breakfast)")
    parser.add_argument("--episodes", type=int, default=5, help="demonstrations to try (default 5)")
    parser.add_argument("--slack", type=float, default=1.5, help="rollout length / demo length (default 1.5)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy = SkillRetPolicy.from_pretrained(args.checkpoint)
    columns = EpisodeColumns.from_dataset(f"local/{args.demos.name}", args.demos)
    sampler = WindowSampler(columns, history=policy.config.history, horizon=policy.config.horizon)
    episodes = load_kitchen_meta(args.demos)["episodes"][: args.episodes]
    episode_index = columns.td["episode_index"].numpy()
    env, solved = KitchenEnv(task=args.task), 0
    for episode in episodes:
        first = int(np.flatnonzero(episode_index == episode["episode_index"])[0])
        length = int(columns.td["episode_end"][first]) - first
        success, unmet = run_episode(
            policy, env, sampler, first, length, np.asarray(episode["initial_state"]), args.slack
        )
        solved += success
        print(f"demo {episode['episode_index']}: {length} steps, success={success}, unmet={unmet}", flush=True)
    print(f"oracle-skill success: {solved}/{len(episodes)}")


if __name__ == "__main__":
    main()
