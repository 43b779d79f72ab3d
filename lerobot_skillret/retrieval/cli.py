"""`skillret-retrieve`: retrieve prior windows for a target task with a stage-1 skill checkpoint.

Examples:
  skillret-retrieve --checkpoint outputs/skills/checkpoints/last/pretrained_model \\
      --prior-repo-id local/play --prior-root data/play \\
      --target-repo-id local/cleaning_up --target-root data/cleaning_up \\
      --output outputs/retrieval/cleaning_up.safetensors --report-dir outputs/retrieval/cleaning_up_report
  skillret-retrieve ... --ablation random          # appendix A.4's "random retrieval"
  skillret-retrieve ... --fraction 0.02            # "2% retrieval"
  skillret-retrieve ... --num-prior all            # "large retrieval": every prior window is a candidate
  skillret-retrieve ... --metric kl                # appendix A.2: symmetric KL between the encoder Gaussians

Unset options take the checkpoint config's values (retrieval_fraction, retrieval_metric, retrieval_num_prior,
retrieval_num_target), whose defaults (the paper's) are shown with each option above.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.retrieval.settings import ABLATIONS, EVERY_WINDOW, METRICS, MODES, RetrievalSettings, ablation

DEFAULTS = RetrievalSettings()  # execution defaults shown in --help


def _num_prior(text: str) -> int | str:
    if text == EVERY_WINDOW:
        return EVERY_WINDOW
    try:
        return int(text.replace("_", ""))
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"expected a number of windows or '{EVERY_WINDOW}', got {text!r}") from error


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="skillret-retrieve",
        description="Encode prior and target windows with a stage-1 skillret checkpoint and keep the prior windows "
        "whose skill latents lie closest to the target's (Algorithm 2, lines 1-7). Writes the retrieval file "
        "that stage 2 reads with --policy.retrieval_path.",
        epilog=__doc__.split("\n", 2)[2],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    io = parser.add_argument_group("inputs and outputs")
    io.add_argument(
        "--checkpoint",
        required=True,
        type=Path,
        help="stage-1 checkpoint: the `pretrained_model` folder (or the checkpoint folder holding it)",
    )
    io.add_argument("--prior-root", required=True, type=Path, help="local folder of the prior (play) dataset")
    io.add_argument("--prior-repo-id", help="repo id of the prior dataset (default: local/<folder name>)")
    io.add_argument("--target-root", required=True, type=Path, help="local folder of the target demos dataset")
    io.add_argument("--target-repo-id", help="repo id of the target dataset (default: local/<folder name>)")
    io.add_argument("--output", required=True, type=Path, help="retrieval file to write (.safetensors, atomic)")
    io.add_argument("--report-dir", type=Path, help="also write summary.json and PNG plots into this folder")
    io.add_argument(
        "--relevant-primitives",
        help="comma-separated primitive names the target task uses: the report then states retrieval precision",
    )

    paper = parser.add_argument_group("retrieval (the paper's knobs; unset = the checkpoint config's value)")
    paper.add_argument(
        "--ablation",
        choices=sorted(ABLATIONS),
        default="nearest",
        help="a row of appendix A.4 (a row that is a mode has its name); the options below override it "
        "(default: nearest, the method)",
    )
    paper.add_argument("--mode", choices=MODES, help="nearest (the method), random, all or none")
    paper.add_argument(
        "--fraction",
        type=float,
        help=f"r: share of candidates retrieved, in (0, 1] (config default {SkillRetConfig.retrieval_fraction})",
    )
    paper.add_argument(
        "--metric",
        choices=METRICS,
        help=f"l2 on encoder means, or symmetric KL (A.2) (config default {SkillRetConfig.retrieval_metric})",
    )
    paper.add_argument(
        "--num-prior",
        type=_num_prior,
        help=f"N candidate windows drawn from the prior, or '{EVERY_WINDOW}' "
        f"(config default {SkillRetConfig.retrieval_num_prior:,})",
    )
    paper.add_argument(
        "--num-target",
        type=int,
        help=f"M target windows encoded (config default {SkillRetConfig.retrieval_num_target:,})",
    )
    paper.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")

    run = parser.add_argument_group("execution")
    run.add_argument(
        "--exact",
        action=argparse.BooleanOptionalAction,
        help="settle windows near the cut in float64, so the set equals a float64 brute force (default true)",
    )
    run.add_argument("--batch-size", type=int, help=f"windows per encoder forward pass (default {DEFAULTS.batch_size})")
    run.add_argument(
        "--chunk-size",
        type=int,
        help=f"prior rows per distance block (default {DEFAULTS.chunk_size}: its [rows, M] block stays in cache)",
    )
    run.add_argument("--device", help="torch device for the encoder (default: the checkpoint's, if available)")
    run.add_argument("--quiet", action="store_true", help="no progress bars")
    return parser


def as_arguments(options: Mapping[str, Any]) -> list[str]:
    """{"num_prior": 1000, "exact": False} -> ["--num-prior=1000", "--no-exact"]: options a pipeline config gives, in
    this CLI's form. Raises ValueError for an option it does not have or a value it cannot take, so that a config
    is refused before any stage runs rather than when its retrieval stage starts."""
    argv = []
    for key, value in options.items():
        flag = key.replace("_", "-")
        argv.append((f"--{flag}" if value else f"--no-{flag}") if isinstance(value, bool) else f"--{flag}={value}")
    parser = build_parser()
    parser.exit_on_error = False
    inputs = [f"--{name}=_" for name in ("checkpoint", "prior-root", "target-root", "output")]
    try:
        args, unknown = parser.parse_known_args([*inputs, *argv])
    except argparse.ArgumentError as error:
        raise ValueError(f"skillret-retrieve refuses {error}") from None
    if unknown:
        raise ValueError(f"skillret-retrieve has no option {unknown[0]} (see skillret-retrieve --help)")
    settings_from_args(args).resolve()  # the settings' own checks (e.g. a fraction in (0, 1])
    return argv


def settings_from_args(args: argparse.Namespace) -> RetrievalSettings:
    """The ablation's settings, overridden by every option given explicitly."""
    given = {}
    for name in ("mode", "fraction", "metric", "num_prior", "num_target", "exact", "batch_size", "chunk_size"):
        if getattr(args, name) is not None:
            given[name] = getattr(args, name)
    return ablation(args.ablation, seed=args.seed, **given)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from lerobot_skillret.retrieval.api import retrieve

    relevant = [name.strip() for name in args.relevant_primitives.split(",")] if args.relevant_primitives else None
    try:
        settings = settings_from_args(args)
        result = retrieve(
            args.checkpoint,
            args.prior_repo_id or f"local/{args.prior_root.name}",
            args.prior_root,
            args.target_repo_id or f"local/{args.target_root.name}",
            args.target_root,
            args.output,
            settings,
            report_dir=args.report_dir,
            relevant_primitives=relevant,
            device=args.device,
            progress=not args.quiet,
        )
    except (FileNotFoundError, ValueError, KeyError) as error:
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        parser.exit(2, f"skillret-retrieve: error: {message}\n")
    used = result.settings
    print(
        f"retrieved {len(result):,} of {used.get('num_candidates', 0):,} prior windows "
        f"(mode {used['mode']}, {used['metric']}, r={used['fraction']:g}, cut={used.get('cut', float('nan')):.4g}) "
        f"-> {args.output}" + (f"; report in {args.report_dir}" if args.report_dir else ""),
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
