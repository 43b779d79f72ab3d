"""Kitchen simulation speed: env steps/s (state only, and with two 84x84 cameras) and generation frames/s.

    MUJOCO_GL=egl python benchmarks/kitchen_speed.py [--steps 300] [--gen-episodes 2 --gen-steps 300]
Goals: >= 100 state-only steps/s per core, >= 25 steps/s with two cameras. Numbers vary with machine load.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")


def env_steps_per_s(cameras: tuple[str, ...], steps: int) -> float:
    import gymnasium as gym

    from lerobot_skillret.kitchen.registration import gym_id, register_envs

    register_envs()
    env = gym.make(gym_id("breakfast"), cameras=cameras, episode_length=10**6)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.3, 0.3, (steps, 7)).astype(np.float32)
    start = time.perf_counter()
    for a in actions:
        env.step(a)
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def generation_frames_per_s(episodes: int, steps: int, workers: int) -> float:
    from lerobot_skillret.kitchen.generate import main

    out = Path(tempfile.mkdtemp()) / "play"
    start = time.perf_counter()
    main(
        [
            "play",
            "--root",
            str(out),
            "--episodes",
            str(episodes),
            "--steps-per-episode",
            str(steps),
            "--workers",
            str(workers),
        ]
    )
    rate = episodes * steps / (time.perf_counter() - start)
    shutil.rmtree(out.parent)
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--gen-episodes", type=int, default=2)
    parser.add_argument("--gen-steps", type=int, default=300)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"env steps/s, state only:        {env_steps_per_s((), args.steps):7.1f}")
    print(f"env steps/s, 2 cameras 84x84:   {env_steps_per_s(('agentview', 'eye_in_hand'), args.steps):7.1f}")
    rate = generation_frames_per_s(args.gen_episodes, args.gen_steps, args.workers)
    print(f"play generation frames/s with {args.workers} workers (incl. start-up and writing): {rate:7.1f}")


if __name__ == "__main__":
    main()
