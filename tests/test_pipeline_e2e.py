"""The whole pipeline at smoke scale through the real CLIs, killed mid-stage and resumed (slow: a few minutes)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lerobot_skillret.data.retrieval_file import RetrievalResult

REPO = Path(__file__).resolve().parents[1]
CLI = str(Path(sys.executable).parent / "skillret-pipeline")
PIPELINE = [CLI, "run", "--config", "configs/pipeline/smoke.yaml"]


@pytest.mark.slow
def test_smoke_pipeline_survives_a_kill_and_produces_every_artifact(tmp_path: Path) -> None:
    out = tmp_path / "run"
    published = tmp_path / "published"
    overrides = [f"--output_dir={out}", f"--results_dir={published}"]
    command = [*PIPELINE, *overrides]
    env = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1"}

    # Kill the whole process group once stage 1 (skill pre-training) is under way.
    proc = subprocess.Popen(
        command, cwd=REPO, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    skills_log = out / "logs" / "skills__prior_seed0.log"
    deadline = time.monotonic() + 900
    while not skills_log.exists():
        assert proc.poll() is None, "the pipeline stopped before stage 1 started"
        assert time.monotonic() < deadline, "stage 1 never started"
        time.sleep(0.5)
    time.sleep(3)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert (out / "data" / "play").is_dir() and not (out / "skills" / "prior_seed0").exists()

    # Re-run: finished stages are skipped, the killed one restarts, everything completes.
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=1500)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "[skip] data/play" in done.stderr and "[run ] skills/prior_seed0" in done.stderr

    assert not list(out.rglob("*.partial")), "a partial artifact was left behind"
    ckpt = out / "skills" / "prior_seed0" / "checkpoints" / "last" / "pretrained_model"
    assert (ckpt / "model.safetensors").is_file()
    retrieved = RetrievalResult.load(out / "retrieval" / "breakfast_skillret_seed0" / "retrieval.safetensors")
    assert len(retrieved) > 0
    report = out / "retrieval" / "breakfast_skillret_seed0" / "report"
    assert {"summary.json", "distance_histogram.png", "latents_pca.png"} <= {p.name for p in report.iterdir()}
    for step in (2, 4):
        info = json.loads(
            (out / "eval" / "skillret" / "breakfast" / "seed0" / f"step{step}" / "eval_info.json").read_text()
        )
        assert all(Path(p).is_file() for p in info["overall"]["video_paths"])
    cell = json.loads((out / "cells" / "skillret" / "breakfast" / "seed0.json").read_text())
    assert 0.0 <= cell["success"] <= 1.0 and cell["best_step"] in (2, 4) and cell["n_episodes"] == 1
    assert "| skillret |" in (out / "results.md").read_text() and (out / "results.png").is_file()
    kept = {p.name for p in (published / "skillret" / "breakfast" / "seed0").iterdir()}
    assert kept == {"cell.json", "eval_step2.json", "eval_step4.json", "retrieval_summary.json"}

    # Offline score of the trained cell on held-out demos (generated once), published beside the cell's eval JSONs.
    heldout = [CLI, "heldout", "--config", "configs/pipeline/smoke.yaml", *overrides, "--heldout.episodes=1"]
    scored = subprocess.run(heldout, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert scored.returncode == 0, scored.stderr[-3000:]
    assert "[run ] heldout/seed7_n1/demos_breakfast" in scored.stderr
    errors = json.loads((published / "skillret" / "breakfast" / "seed0" / "heldout_error.json").read_text())
    assert [row["step"] for row in errors["checkpoints"]] == [2, 4] and errors["frames"] > 0
    assert all(0.0 <= row[k] < float("inf") for row in errors["checkpoints"] for k in ("policy", "oracle"))
    for report in (out / "results.md", published / "results.md"):
        assert "| skillret |" in report.read_text().split("### Held-out imitation error")[1]
