"""`skillret-generate`'s worker pool: no deadlock on early stop, workers end with the parent, no stale folders."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from lerobot_skillret.kitchen import generate as G
from lerobot_skillret.kitchen.collect import Episode, EpisodeJob

BIN = Path(sys.executable).parent
FRAMES = 2_000_000  # floats per episode (16 MB): real episodes are large, and fill any pipe they are sent through


def _fake_episode(job: EpisodeJob) -> Episode:
    """Stands in for a simulated episode (runs in the spawned workers): the first is quick, the others take a
    second, so the stream is left while workers are still simulating or sending episodes back."""
    time.sleep(0.05 if job.seed == 0 else 1.0)
    return Episode(
        seed=job.seed, task="breakfast", success=True, initial_state=np.zeros(3), frames={"x": np.zeros(FRAMES)}
    )


def _workers(pid: int | None = None) -> list[psutil.Process]:
    """The spawned pool workers among the children of `pid` (not multiprocessing's resource tracker)."""
    children = psutil.Process(pid).children()
    return [c for c in children if "spawn_main" in " ".join(c.cmdline())]


def _jobs(n: int) -> list[EpisodeJob]:
    return [EpisodeJob("demos", seed, task="breakfast") for seed in range(n)]


@pytest.mark.timeout(60)
def test_early_stop_with_jobs_still_queued_finishes_in_seconds():
    """More workers than needed and 90 queued attempts of which 1 is used: leaving the stream must kill the pool
    at once. The `Pool.imap` this replaces blocked forever in `Pool.terminate()` (a worker writing its episode into
    the shared result queue, whose reader had stopped)."""
    with G._episode_stream(_jobs(90), workers=4, simulate=_fake_episode) as stream:
        first = next(iter(stream))
        workers = _workers()
        assert len(workers) == 4
    assert first.seed == 0
    _, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, f"workers outlived the stream: {alive}"


def test_stream_keeps_job_order_and_yields_every_episode():
    with G._episode_stream(_jobs(7), workers=3, simulate=_fake_episode) as stream:
        assert [episode.seed for episode in stream] == list(range(7))
    with G._episode_stream(_jobs(2), workers=5, simulate=_fake_episode) as stream:  # more workers than jobs
        assert [episode.seed for episode in stream] == [0, 1]


@pytest.mark.slow
def test_killed_run_leaves_no_stale_folder_and_no_workers(tmp_path):
    """SIGKILL mid-run: the workers die with the parent; the re-run removes the killed run's temporary folder."""
    root = tmp_path / "play"
    argv = [str(BIN / "skillret-generate"), "play", "--root", str(root), "--workers", "2"]
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    proc = subprocess.Popen([*argv, "--episodes", "50", "--steps-per-episode", "400"], env=env)
    tmp = tmp_path / f".play.tmp-{proc.pid}"
    deadline = time.monotonic() + 120
    while not (tmp.exists() and len(_workers(proc.pid)) == 2):
        assert proc.poll() is None and time.monotonic() < deadline, "generation did not start its workers"
        time.sleep(0.2)
    workers = _workers(proc.pid)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # A worker killed while still importing (before its prctl) exits once it reads the closed pipe: on a loaded
    # machine that import alone took over 15 s.
    _, alive = psutil.wait_procs(workers, timeout=90)
    assert not alive, "simulation workers outlived the killed generator"
    assert tmp.exists()  # SIGKILL leaves it; the next run must clean it

    subprocess.run([*argv, "--episodes", "1", "--steps-per-episode", "20"], env=env, check=True, timeout=300)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["play"]


@pytest.mark.slow
def test_sigterm_removes_the_temporary_folder(tmp_path):
    root = tmp_path / "play"
    proc = subprocess.Popen(
        [str(BIN / "skillret-generate"), "play", "--root", str(root), "--workers", "1", "--episodes", "50"],
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    tmp = tmp_path / f".play.tmp-{proc.pid}"
    deadline = time.monotonic() + 120
    while not tmp.exists():
        assert proc.poll() is None and time.monotonic() < deadline, "generation did not start"
        time.sleep(0.2)
    proc.terminate()
    assert proc.wait(timeout=60) != 0
    assert list(tmp_path.iterdir()) == []


def test_an_expert_that_keeps_failing_is_a_clear_error_and_leaves_no_dataset(tmp_path, monkeypatch):
    """A task whose scripted expert never succeeds (a user's new task with a bad plan) stops with the reason, not
    a traceback, after its 3x attempts; nothing is left at --root."""

    def failed(job: EpisodeJob) -> Episode:
        return Episode(seed=job.seed, task="breakfast", success=False, initial_state=np.zeros(3), frames={})

    monkeypatch.setattr(G, "run_episode", failed)
    root = tmp_path / "demos"
    args = ["demos", "--task", "breakfast", "--episodes", "2", "--workers", "0", "--root", str(root)]
    with pytest.raises(SystemExit) as stop:
        G.main(args)
    assert "only 0 of 2 successful demos in 6 attempts" in str(stop.value.code)
    assert str(stop.value.code).startswith("skillret-generate: ")
    assert not root.exists() and list(tmp_path.iterdir()) == []


def test_overwrite_replaces_only_a_dataset_never_another_folder_or_a_file(tmp_path):
    """`--overwrite` replaces its --root whole: a folder of other files (or a file) is refused before any
    simulation, and left as it was."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me too")
    cases = [(mine, "already holds other files"), (a_file, "is a file"), (a_file / "sub", f"{a_file} is a file")]
    for root, reason in cases:
        for overwrite in (["--overwrite"], []):  # without it a file was "already exists; pass --overwrite"
            args = ["play", "--episodes", "1", "--steps-per-episode", "5", "--workers", "0", *overwrite]
            with pytest.raises(SystemExit) as stop:
                G.main([*args, "--root", str(root)])
            assert reason in str(stop.value.code) and "--root" in str(stop.value.code)
    assert (mine / "notes.txt").read_text() == "keep me" and a_file.read_text() == "keep me too"


def test_negative_seed_is_refused_in_one_line():
    with pytest.raises(SystemExit) as stop:
        G.main(["play", "--root", "unused", "--seed", "-1"])
    assert "--seed >= 0" in str(stop.value.code)
