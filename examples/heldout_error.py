"""How closely do trained skillret policies imitate demonstrations they never saw? An offline comparison of
checkpoints (methods, ablations, seeds) without the noise of a few rollouts.

Generate held-out demonstrations with another generation seed than the training ones, then score checkpoints:

    skillret-generate demos --task breakfast --episodes 10 --seed 7 --root outputs/heldout/demos_breakfast
    python examples/heldout_error.py --demos outputs/heldout/demos_breakfast \\
        --checkpoints outputs/benchmark/train/*/breakfast/seed0/checkpoints/last/pretrained_model

For every window that starts a skill at rollout (every H steps of each episode), the latent policy picks a skill
from the F observations before it and the closed-loop decoder runs it along the demonstration's own observations
(`SkillRetPolicy.imitation_error`). Printed per checkpoint: the mean action error of the policy's skills and of the
oracle skills (the checkpoint's encoder applied to the window itself, the floor that this decoder allows).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy


def skill_starts(columns: EpisodeColumns, horizon: int) -> torch.Tensor:
    """Global frame indices where a rollout would query the policy: every H steps from each episode's start."""
    start = columns.td["episode_start"].as_subclass(torch.Tensor)
    frames = torch.arange(len(columns))
    return frames[(frames - start) % horizon == 0]


def score(checkpoint: Path, columns: EpisodeColumns) -> dict[str, float]:
    policy = SkillRetPolicy.from_pretrained(checkpoint).eval()
    config = policy.config
    if config.stage != "policy":
        raise ValueError(f"{checkpoint} is a stage-1 (skills) checkpoint; score stage-2 (policy) checkpoints.")
    sampler = WindowSampler(columns, config.history, config.horizon, keys=[*policy.low_dim_keys, "action"])
    errors = policy.imitation_error(sampler.gather(skill_starts(columns, config.horizon)))
    return {name: float(value.mean()) for name, value in errors.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demos", required=True, type=Path, help="held-out demos (`skillret-generate demos`)")
    parser.add_argument("--checkpoints", required=True, nargs="+", type=Path, help="stage-2 `pretrained_model` folders")
    args = parser.parse_args()
    torch.set_grad_enabled(False)
    columns = EpisodeColumns.from_dataset(f"local/{args.demos.name}", args.demos)  # a local root: any repo id
    print(f"{len(columns)} held-out frames in {args.demos}")
    print(f"{'policy error':>12}  {'oracle error':>12}  checkpoint")
    for checkpoint in args.checkpoints:
        result = score(checkpoint, columns)
        print(f"{result['policy']:12.4f}  {result['oracle']:12.4f}  {checkpoint}")


if __name__ == "__main__":
    main()
