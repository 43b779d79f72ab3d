"""Can the skill decoder execute a task's demonstrations when it is handed the right skills?

Every H steps the checkpoint's encoder encodes the demonstration's own window (the oracle latent) and the
closed-loop decoder executes it from the demonstration's initial state (`lerobot_skillret.pipeline.oracle`). High
success here and low success of the trained policy points at the latent policy; low success here points at the
skill model. With `--swap k` each rollout executes the latents of the demonstration k places on from its own initial
state: skills that generalise still succeed, latents that replay one demonstration's motion do not. `--trace` prints,
per rollout, the demonstration step nearest the robot at every skill and the sub-goals met so far (with
`--policy-every 1`: where the latent policy's own rollout leaves the demonstration).
`benchmarks/skill_study.py` runs it over stage-1 training steps, prior sizes and the task ladder.

    MUJOCO_GL=egl python examples/oracle_skills.py \\
        --checkpoint outputs/demo/train/skillret/open_drawer/seed0/checkpoints/last/pretrained_model \\
        --demos outputs/demo/data/demos_open_drawer --task open_drawer --episodes 5
"""

import argparse
from pathlib import Path

import torch

from lerobot_skillret.pipeline.oracle import oracle_success


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True, type=Path, help="a skillret `pretrained_model` folder")
    parser.add_argument("--demos", required=True, type=Path, help="a demos dataset made by `skillret-generate demos`")
    parser.add_argument("--task", required=True, help="the demos' task (e.g. open_drawer)")
    parser.add_argument("--episodes", type=int, default=5, help="demonstrations to try (default 5)")
    parser.add_argument("--slack", type=float, default=1.5, help="rollout length / demo length (default 1.5)")
    parser.add_argument(
        "--align",
        action="store_true",
        help="pick each latent by the robot's phase (nearest demo observation ahead) instead of the demo's clock",
    )
    parser.add_argument(
        "--policy-every",
        type=int,
        default=0,
        help="every n-th skill is the stage-2 latent policy's own choice (0: none, 1: all, 2: every other)",
    )
    parser.add_argument(
        "--swap",
        type=int,
        default=0,
        help="start from each demo's initial state but execute the latents of the demo this many places on (0: its "
        "own): do the skills carry over to other object positions, or replay one demo's motion?",
    )
    parser.add_argument(
        "--discrete-gripper",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="round the gripper command to open / hold / close, as the env does by default "
        "(`--no-discrete-gripper`: the continuous command of the results before 2026-12-05)",
    )
    parser.add_argument(
        "--trace",
        action="store_true",
        help="print, at every skill, the demo step nearest the robot's state and the sub-goals met so far: where a "
        "rollout leaves its demo, stalls, or loops back to retry a step",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    try:
        result = oracle_success(
            args.checkpoint,
            args.demos,
            args.task,
            args.episodes,
            args.slack,
            args.align,
            args.policy_every,
            args.swap,
            args.discrete_gripper,
            args.trace,
        )
    except (FileNotFoundError, ValueError, KeyError) as error:  # bad input: one line naming it, no traceback
        parser.exit(2, f"oracle_skills: {error.args[0] if isinstance(error, KeyError) else error}\n")
    swapped = f" (each executing the latents of the demo {args.swap} on)" if args.swap else ""
    print(
        f"oracle-skill success: {result['success']:.0%} of {result['episodes']} demos{swapped}, sub-goals met "
        f"{result['goals_met']:.0%}, teacher-forced oracle action error {result['oracle_action_error']:.4f} (other "
        f"windows' skills: {result['shuffled_action_error']:.3f}; the demos' mean action held constant: "
        f"{result['mean_action_error']:.3f})"
    )


if __name__ == "__main__":
    main()
