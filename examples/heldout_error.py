"""How closely do trained skillret policies imitate demonstrations they never saw? An offline comparison of
checkpoints (methods, ablations, seeds) without the noise of a few rollouts.

Generate held-out demonstrations with another generation seed than the training ones, then score checkpoints:

    skillret-generate demos --task bread_and_butter --episodes 10 --seed 7 --root outputs/heldout/demos_bread_and_butter
    python examples/heldout_error.py --demos outputs/heldout/demos_bread_and_butter \\
        --checkpoints outputs/benchmark/train/{skillret,no_retrieval,no_prior}/bread_and_butter/seed0/checkpoints/last/pretrained_model

Printed per checkpoint: the mean action error of the policy's skills and of the oracle skills (see
`lerobot_skillret.pipeline.heldout`). For a pipeline's own cells, `skillret-pipeline heldout --config <config>` does
the same for every trained skillret variant and adds the table to the results.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lerobot_skillret.data.windows import EpisodeColumns
from lerobot_skillret.pipeline.heldout import imitation_errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demos", required=True, type=Path, help="held-out demos (`skillret-generate demos`)")
    parser.add_argument("--checkpoints", required=True, nargs="+", type=Path, help="stage-2 `pretrained_model` folders")
    args = parser.parse_args()
    columns = EpisodeColumns.from_dataset(f"local/{args.demos.name}", args.demos)  # a local root: any repo id
    print(f"{len(columns)} held-out frames in {args.demos}")
    print(f"{'policy error':>12}  {'oracle error':>12}  checkpoint")
    for checkpoint in args.checkpoints:
        result = imitation_errors(checkpoint, columns)
        print(f"{result['policy']:12.4f}  {result['oracle']:12.4f}  {checkpoint}")


if __name__ == "__main__":
    main()
