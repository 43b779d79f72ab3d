"""Data-parallel training: both stages through `lerobot-train` as 2 ranks (torchrun, gloo on CPU; on GPUs
`accelerate launch --multi_gpu` starts the same processes). Each rank must draw its own windows, and all read one
retrieved set."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest
from policy_fixtures import PRIOR_REPO, QUICK_TRAIN, TARGET_REPO, TINY_CLI, TRAIN_ENV, stage2_cli, write_retrieval
from synthetic import make_synthetic_dataset

pytestmark = pytest.mark.slow

BIN = Path(sys.executable).parent
RANK_LINE = re.compile(r"skillret data-parallel: 2 ranks, same retrieved set \((\d+) windows\); per rank: (.*)")


def train_on_two_ranks(*args: str) -> str:
    """`torchrun --nproc_per_node 2 lerobot-train ...`; returns the combined log."""
    result = subprocess.run(
        [
            str(BIN / "torchrun"),
            "--standalone",
            "--nproc_per_node=2",
            str(BIN / "lerobot-train"),
            *QUICK_TRAIN,
            "--log_freq=1",
            *TINY_CLI,
            *args,
        ],
        env=TRAIN_ENV,
        capture_output=True,
        text=True,
        timeout=600,
    )
    log = result.stdout + result.stderr
    assert result.returncode == 0, log[-6000:]
    return log


def ranks_in(log: str) -> tuple[int, list[tuple[list[int], list[int]]]]:
    """(retrieved windows, [(seeds, first anchors) per rank]) from the policy's data-parallel log line."""
    match = RANK_LINE.search(log)
    assert match, "the main process did not log the ranks' windows:\n" + log[-4000:]
    print(match.group(0))  # shown with `pytest -s`: the evidence the ranks drew different windows
    per_rank = re.findall(r"rank \d+: seeds (\[[^\]]*\]), first anchors (\[[^\]]*\])", match.group(2))
    return int(match.group(1)), [(ast.literal_eval(s), ast.literal_eval(a)) for s, a in per_rank]


def test_both_stages_train_on_two_ranks_with_their_own_windows(tmp_path):
    prior = make_synthetic_dataset(tmp_path / "prior", PRIOR_REPO, num_episodes=5, seed=0)
    target = make_synthetic_dataset(tmp_path / "target", TARGET_REPO, num_episodes=3, seed=1)

    log = train_on_two_ranks(
        "--policy.stage=skills",
        f"--dataset.repo_id={PRIOR_REPO}",
        f"--dataset.root={prior}",
        f"--output_dir={tmp_path / 'stage1'}",
    )
    retrieved, ranks = ranks_in(log)
    assert retrieved == 0 and len(ranks) == 2
    (seeds0, anchors0), (seeds1, anchors1) = ranks
    assert seeds0 != seeds1 and anchors0 != anchors1, ranks
    stage1 = tmp_path / "stage1" / "checkpoints" / "last" / "pretrained_model"
    assert (stage1 / "model.safetensors").is_file()

    indices = [2, 11, 40, 63, 77]
    retrieval = write_retrieval(tmp_path / "retrieval.safetensors", stage1, prior, target, indices)

    log = train_on_two_ranks(
        *stage2_cli(stage1, target, prior, retrieval, tmp_path / "stage2"),
    )
    retrieved, ranks = ranks_in(log)
    assert retrieved == len(indices)  # every rank read the same retrieved set (checked across ranks)
    (seeds0, anchors0), (seeds1, anchors1) = ranks
    assert len(seeds0) == 2 and not set(seeds0) & set(seeds1), ranks  # target pairs and prior/retrieved windows
    assert anchors0 != anchors1, ranks
    assert (tmp_path / "stage2" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file()
