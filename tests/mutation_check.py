"""Mutation check: does the fast test suite notice small, plausible bugs in the method's core?

Each mutant replaces one exact snippet of `policy/`, `retrieval/` or the held-out scoring with a wrong variant,
runs the fast tests of the parts it touches, and restores the file (also on Ctrl-C). A mutant that no test kills is
a hole in the suite. Not part of `make test` (it runs the suite once per mutant, minutes in all):

    python tests/mutation_check.py            # every mutant
    python tests/mutation_check.py --list     # what each one breaks
    python tests/mutation_check.py labels kl  # some, by name
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "lerobot_skillret"
POLICY_TESTS = [
    "tests/test_policy_model.py",
    "tests/test_policy_method_pins.py",
    "tests/test_policy_lerobot_contract.py",
]
RETRIEVAL_TESTS = [
    "tests/test_retrieval_kernels.py",
    "tests/test_retrieval_selection.py",
    "tests/test_retrieval_api.py",
]


@dataclass(frozen=True)
class Mutant:
    name: str
    what: str
    path: Path
    old: str
    new: str
    tests: tuple[str, ...]


MUTANTS = [
    Mutant(
        "labels",
        "stage-2 target labels taken from the prior windows' latents",
        PKG / "policy/modeling_skillret.py",
        "labels = means[:size].detach()",
        "labels = means[-size:].detach()",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "decoder_state",
        "decoder LSTM state not reset when a new skill starts",
        PKG / "policy/modeling_skillret.py",
        "            self._skill = self._choose_skill()\n            self._decoder_state = None\n",
        "            self._skill = self._choose_skill()\n",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "history_prefill",
        "observation history not pre-filled with the first observation at reset",
        PKG / "policy/modeling_skillret.py",
        "self._history_frames.extend([frame] * self.config.history)",
        "self._history_frames.append(frame)",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "heldout_points",
        "held-out scoring points shifted by one step",
        PKG / "pipeline/heldout.py",
        "frames[(frames - start) % horizon == 0]",
        "frames[(frames - start) % horizon == 1]",
        ("tests/test_policy_method_pins.py", "tests/test_pipeline_runner.py"),
    ),
    Mutant(
        "kl_order",
        "KL(p || q) computed instead of KL(q || p)",
        PKG / "policy/skills.py",
        "return kl_divergence(q, p).sum(dim=-1)",
        "return kl_divergence(p, q).sum(dim=-1)",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "pairs_untrained",
        "stage-1 temporal pairs encoded for the temporal term but never reconstructed",
        PKG / "policy/modeling_skillret.py",
        "self._skill_loss([(batch, data.own)], decode_pairs=True)",
        "self._skill_loss([(batch, data.own)], decode_pairs=False)",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "pair_means",
        "temporal term fed the anchors' means twice instead of the anchor's and its pair's",
        PKG / "policy/skills.py",
        "pair_mean = means[batch : 2 * batch]",
        "pair_mean = means[:batch]",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "retrieved_id",
        "retrieved windows conditioned on the target's dataset id",
        PKG / "policy/modeling_skillret.py",
        "retrieved_ids = torch.full((size,), RETRIEVED_ID,",
        "retrieved_ids = torch.full((size,), TARGET_ID,",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "retrieved_weight",
        "gamma ignored: retrieved loss always weighted 1",
        PKG / "policy/modeling_skillret.py",
        "policy_loss = policy_loss + config.retrieved_weight * retrieved_loss",
        "policy_loss = policy_loss + retrieved_loss",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "padded_steps",
        "padded steps past an episode's end counted as valid",
        PKG / "policy/modeling_skillret.py",
        "~pad.to(self._device(), torch.bool)",
        "torch.ones_like(pad, dtype=torch.bool, device=self._device())",
        tuple(POLICY_TESTS),
    ),
    Mutant(
        "retrieve_farthest",
        "retrieval keeps the farthest candidates instead of the nearest",
        PKG / "retrieval/kernels.py",
        "rows = torch.topk(value, count, largest=False, sorted=False).indices",
        "rows = torch.topk(value, count, largest=True, sorted=False).indices",
        tuple(RETRIEVAL_TESTS),
    ),
    Mutant(
        "retrieval_count",
        "K rounded down instead of round(r * candidates)",
        PKG / "retrieval/api.py",
        "return round(fraction * num_candidates)",
        "return int(fraction * num_candidates)",
        tuple(RETRIEVAL_TESTS),
    ),
    Mutant(
        "exact_band",
        "rows near the cut not re-scored exactly (float32 set instead of float64's)",
        PKG / "retrieval/kernels.py",
        "band = torch.nonzero(~sure_in & (low <= cut_high)).squeeze(1)",
        "band = torch.nonzero(~sure_in & (low < cut_low)).squeeze(1)",
        tuple(RETRIEVAL_TESTS),
    ),
]


def run(mutant: Mutant, timeout: int) -> tuple[bool, float]:
    """(killed, seconds): apply `mutant`, run its tests, restore the file."""
    original = mutant.path.read_text()
    if original.count(mutant.old) != 1:
        raise SystemExit(f"mutant {mutant.name}: the snippet to replace is not in {mutant.path} exactly once")
    start = time.monotonic()
    try:
        mutant.path.write_text(original.replace(mutant.old, mutant.new))
        tests = [t for t in mutant.tests if (ROOT / t).is_file()]  # an older checkout may lack some
        result = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-x", "-m", "not slow", "-p", "no:cacheprovider", *tests],
            cwd=ROOT,
            env={**os.environ, "HF_HUB_OFFLINE": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")},
            capture_output=True,
            timeout=timeout,
        )
        killed = result.returncode != 0
    except subprocess.TimeoutExpired:
        killed = True  # a hang is a detected failure too
    finally:
        mutant.path.write_text(original)
    return killed, time.monotonic() - start


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("names", nargs="*", help="mutants to run (default: all)")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--timeout", type=int, default=900, help="seconds per mutant")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))  # restore the file on `kill` too
    known = {m.name: m for m in MUTANTS}
    if args.list:
        for m in MUTANTS:
            print(f"{m.name:18s} {m.what}  ({m.path.relative_to(ROOT)})")
        return
    unknown = [n for n in args.names if n not in known]
    if unknown:
        parser.error(f"unknown mutant(s) {unknown}; --list shows {sorted(known)}")
    survivors = []
    for mutant in [known[n] for n in args.names] or MUTANTS:
        killed, seconds = run(mutant, args.timeout)
        print(f"{'killed  ' if killed else 'SURVIVED'} {mutant.name:18s} {seconds:5.0f} s  {mutant.what}", flush=True)
        survivors += [] if killed else [mutant.name]
    print(f"{len(survivors)} surviving mutant(s){': ' + ', '.join(survivors) if survivors else ''}")
    sys.exit(1 if survivors else 0)


if __name__ == "__main__":
    main()
