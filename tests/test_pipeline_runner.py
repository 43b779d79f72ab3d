"""The pipeline's stage runner, config and results table, without the simulator (fast)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from lerobot_skillret.pipeline.config import EvalSpec, PipelineConfig, RetrievalSpec, TrainSpec
from lerobot_skillret.pipeline.plan import Cell, Plan
from lerobot_skillret.pipeline.protocol import summarise_cell
from lerobot_skillret.pipeline.results import (
    HELDOUT_FILE,
    PUBLISHED_HELDOUT,
    bar_plot,
    collect,
    markdown_report,
    markdown_table,
)
from lerobot_skillret.pipeline.stages import Stage, StageRunner


def writer_stage(tmp_path: Path, name: str, sleep: float = 0.0, fail: bool = False) -> Stage:
    """A stage whose command slowly writes a folder of two files into the partial path."""
    stage = Stage(name, tmp_path / "out" / name)
    code = textwrap.dedent(f"""
        import pathlib, sys, time
        p = pathlib.Path({str(stage.partial)!r}); p.mkdir()
        (p / "a.txt").write_text("a"); time.sleep({sleep}); (p / "b.txt").write_text("b")
        sys.exit({1 if fail else 0})
    """)
    stage.command = [sys.executable, "-c", code]
    return stage


def test_stage_publishes_only_on_success_and_skips_when_done(tmp_path: Path) -> None:
    runner = StageRunner(tmp_path / "out")
    ok = writer_stage(tmp_path, "ok")
    assert runner.run(ok) is True
    assert sorted(p.name for p in ok.output.iterdir()) == ["a.txt", "b.txt"] and not ok.partial.exists()
    assert runner.run(ok) is False  # finished stages are never redone
    assert runner.timing("ok") is not None

    bad = writer_stage(tmp_path, "bad", fail=True)
    with pytest.raises(RuntimeError, match="stage bad failed \\(exit code 1\\)"):
        runner.run(bad)
    assert not bad.output.exists()


def test_a_finished_stage_built_by_another_command_is_refused_not_reused(tmp_path: Path) -> None:
    """A config changed between runs (e.g. more play episodes) must not silently reuse the old artifact."""
    runner = StageRunner(tmp_path / "out")
    assert runner.run(writer_stage(tmp_path, "data")) is True
    assert runner.run(writer_stage(tmp_path, "data")) is False  # same command: skipped
    changed = writer_stage(tmp_path, "data", sleep=0.01)
    with pytest.raises(RuntimeError, match=r"built with other options.*Delete .*data to rebuild"):
        runner.run(changed)
    assert sorted(p.name for p in changed.output.iterdir()) == ["a.txt", "b.txt"]  # nothing was touched


def test_two_runners_sharing_a_folder_build_a_stage_once(tmp_path: Path) -> None:
    """Two pipeline processes on one output folder: the second waits for the stage lock, then skips the stage."""
    from concurrent.futures import ThreadPoolExecutor

    counter = tmp_path / "runs.txt"

    def stage() -> Stage:
        s = writer_stage(tmp_path, "shared", sleep=1.0)
        s.command[-1] = f"open({str(counter)!r}, 'a').write('x')\n" + s.command[-1]
        return s

    runners = [StageRunner(tmp_path / "out") for _ in range(2)]
    with ThreadPoolExecutor(2) as pool:
        ran = sorted(pool.map(lambda r: r.run(stage()), runners))
    assert ran == [False, True] and counter.read_text() == "x"
    assert sorted(p.name for p in (tmp_path / "out" / "shared").iterdir()) == ["a.txt", "b.txt"]


def test_killed_run_leaves_no_artifact_and_reruns_cleanly(tmp_path: Path) -> None:
    """SIGKILL the whole process group mid-stage: the next run redoes only that stage, from scratch."""
    first, slow = writer_stage(tmp_path, "first"), writer_stage(tmp_path, "slow", sleep=30)
    script = tmp_path / "drive.py"
    script.write_text(
        textwrap.dedent(f"""
        import pickle, sys
        from pathlib import Path
        from lerobot_skillret.pipeline.stages import Stage, StageRunner
        stages = pickle.loads(Path({str(tmp_path / "stages.pkl")!r}).read_bytes())
        runner = StageRunner(Path({str(tmp_path / "out")!r}))
        print([runner.run(s) for s in stages], flush=True)
    """)
    )
    import pickle

    (tmp_path / "stages.pkl").write_bytes(pickle.dumps([first, slow]))
    proc = subprocess.Popen([sys.executable, str(script)], start_new_session=True, stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (slow.partial / "a.txt").exists():
        assert time.monotonic() < deadline and proc.poll() is None, "the slow stage never started"
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert first.output.exists() and not slow.output.exists() and slow.partial.exists()

    fast_slow = writer_stage(tmp_path, "slow", sleep=0)
    (tmp_path / "stages.pkl").write_bytes(pickle.dumps([first, fast_slow]))
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[False, True]"  # first skipped, slow redone
    assert sorted(p.name for p in slow.output.iterdir()) == ["a.txt", "b.txt"] and not slow.partial.exists()


def test_config_rejects_typos_and_missing_baselines(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text("tasks: [cook]\nevall: {n_episodes: 3}\n")
    with pytest.raises(ValueError, match="`evall` are not valid"):
        PipelineConfig.from_args(path)
    path.write_text("methods: [skillret, act]\n")
    with pytest.raises(ValueError, match=r"`act` needs a `baselines\.act` section"):
        PipelineConfig.from_args(path)
    path.write_text("tasks: [brekfast]\n")
    with pytest.raises(ValueError, match="unknown tasks \\['brekfast'\\]"):
        PipelineConfig.from_args(path)
    path.write_text("data: {cameras: true}\n")
    with pytest.raises(ValueError, match=r"data\.cameras"):
        PipelineConfig.from_args(path)
    path.write_text("eval: {n_episodes: 2, batch_size: 4}\n")
    with pytest.raises(ValueError, match="batch_size"):
        PipelineConfig.from_args(path)
    cfg = PipelineConfig.from_args(path, ["--eval.batch_size=1", "--policy.args={policy.horizon: 5}"])
    assert cfg.eval.batch_size == 1 and cfg.policy.args == {"policy.horizon": 5}
    path.write_text("eval: {max_checkpoints: 0}\n")  # would slice [-0:], i.e. evaluate every checkpoint
    with pytest.raises(ValueError, match=r"`eval\.max_checkpoints` must be an integer >= 1 \(got 0\)"):
        PipelineConfig.from_args(path)
    path.write_text("heldout: {seed: 0}\n")  # data.seed is 0: the "held-out" demos would be the training ones
    with pytest.raises(ValueError, match=r"`heldout\.seed` equals `data\.seed`=0"):
        PipelineConfig.from_args(path)
    path.write_text("heldout: {episodes: 0}\n")
    with pytest.raises(ValueError, match=r"`heldout\.episodes` must be an integer >= 1 \(got 0\)"):
        PipelineConfig.from_args(path)
    path.write_text("skills: {config_path: configs/policy/cpu.jsn}\n")
    with pytest.raises(FileNotFoundError, match=r"`skills\.config_path` configs/policy/cpu\.jsn not found"):
        PipelineConfig.from_args(path)
    path.write_text("skills: {steps: 1.5}\n")
    with pytest.raises(ValueError, match=r"`skills\.steps`: Couldn't parse '1\.5' into an int"):
        PipelineConfig.from_args(path)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("--skills.steps=abc", r"`skills\.steps`: Couldn't parse 'abc' into an int"),
        ("--policy.steps=1.5", r"`policy\.steps`: Couldn't parse '1\.5' into an int"),
        ("--skills.batch_size=2.5", r"`skills\.batch_size`: Couldn't parse '2\.5' into an int"),
        ("--data.play_episodes=abc", r"`data\.play_episodes`: Couldn't parse 'abc'"),
        ("--data.demo_episodes=-3", r"`data\.demo_episodes` must be >= 1 \(got -3\)"),
        ("--data.workers=abc", r"`data\.workers`: Couldn't parse 'abc'"),
        ("--data.workers=-1", r"`data\.workers` must be >= 0"),
        ("--threads=abc", r"`threads`: Could not decode"),
        ("--threads=0", r"`threads` must be >= 1 or null"),
        ("--seeds=[abc]", r"`seeds\.0`: Couldn't parse 'abc' into an int"),
        ("--tasks=cook", r"`tasks`: Failed when parsing value='cook'"),
        ("--eval.n_episodes=ten", r"`eval\.n_episodes`: Couldn't parse 'ten'"),
        ("--retrieval.args=5", r"`retrieval\.args`: Failed when parsing value='5'"),
        ("eval.n_episodes=10", r"written as for lerobot-train, e\.g\. --eval\.n_episodes=10"),
    ],
)
def test_pipeline_cli_names_values_of_the_wrong_type(override: str, message: str) -> None:
    """Each is refused before any stage runs, naming the key and the value (before: a raw TypeError, or accepted
    and failing later inside a subprocess)."""
    result = subprocess.run(
        [
            str(Path(sys.executable).parent / "skillret-pipeline"),
            "run",
            "--config",
            "configs/pipeline/smoke.yaml",
            override,
            "--output_dir=/nonexistent/never-written",
        ],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert result.returncode != 0
    assert re.search(message, result.stderr), result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    assert not Path("/nonexistent/never-written").exists()


def test_plan_wires_each_ablation(tmp_path: Path) -> None:
    methods = ["skillret", "no_retrieval", "random_retrieval", "all_retrieval", "no_prior"]
    retrieval = RetrievalSpec(args={"fraction": 0.05, "num-prior": 1000})
    plan = Plan(PipelineConfig(output_dir=str(tmp_path), tasks=["cook"], methods=methods, retrieval=retrieval))
    cmds = {m: " ".join(plan.train_stage(Cell(m, "cook", 0)).command) for m in methods}
    assert "--policy.retrieval_path=" in cmds["skillret"] and "cook_skillret_seed0" in cmds["skillret"]
    assert "cook_random_retrieval_seed0" in cmds["random_retrieval"]
    assert "--policy.use_retrieval=false" in cmds["no_retrieval"] and "prior_seed0" in cmds["no_retrieval"]
    assert "target_cook_seed0" in cmds["no_prior"] and "--policy.prior_repo_id=null" in cmds["no_prior"]
    assert "--ablation=random" in " ".join(plan.retrieval_stage("cook", "random_retrieval", 0).command)
    assert "cook_all_retrieval_seed0" in cmds["all_retrieval"]
    all_cmd = plan.retrieval_stage("cook", "all_retrieval", 0).command
    assert "--ablation=all" in all_cmd and not any(a.startswith(("--fraction", "--num-prior")) for a in all_cmd)
    assert "--fraction=0.05" in plan.retrieval_stage("cook", "skillret", 0).command
    exact = Plan(
        PipelineConfig(output_dir=str(tmp_path), tasks=["cook"], retrieval=RetrievalSpec(args={"exact": False}))
    )
    assert "--no-exact" in exact.retrieval_stage("cook", "skillret", 0).command  # argparse's boolean form
    assert not any(a.startswith("--ablation") for a in plan.retrieval_stage("cook", "skillret", 0).command)


def test_a_method_is_one_registry_entry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A new row of the table (here: the paper's 2 % retrieval) needs nothing but its `Method` entry."""
    from lerobot_skillret.pipeline import methods

    entry = methods.Method("r2_retrieval", "skills from the prior, 2 % retrieved", "prior", {"ablation": "r2"})
    monkeypatch.setitem(methods.METHODS, entry.name, entry)
    plan = Plan(PipelineConfig(output_dir=str(tmp_path), tasks=["cook"], methods=["r2_retrieval"]))
    cell = Cell("r2_retrieval", "cook", 0)
    assert "--ablation=r2" in plan.retrieval_stage("cook", cell.method, 0).command
    assert f"--policy.retrieval_path={plan.retrieval_path('cook', cell.method, 0)}" in plan.train_stage(cell).command
    assert plan.needs_prior() and plan.retrieval_summary(cell) is not None


def _cell(root: Path, method: str, task: str, seed: int, success: float, subgoals: float | None = None) -> None:
    path = root / method / task / f"seed{seed}" / "cell.json"
    path.parent.mkdir(parents=True)
    payload = {"method": method, "task": task, "seed": seed, "success": success, "n_episodes": 10}
    if subgoals is not None:
        payload["subgoals"] = subgoals
    path.write_text(json.dumps(payload))


def test_results_table_is_mean_and_std_over_seeds(tmp_path: Path) -> None:
    for seed, s in enumerate([0.5, 0.7, 0.9]):
        _cell(tmp_path, "skillret", "cook", seed, s)
    _cell(tmp_path, "skillret", "breakfast", 0, 0.4)
    _cell(tmp_path, "act", "cook", 0, 0.2)
    table = markdown_table(collect(tmp_path))
    lines = table.splitlines()
    assert lines[0] == "| method | breakfast | cook | average |"
    assert lines[2] == "| skillret | 40.0 ± 0.0 (1) | 70.0 ± 16.3 (3) | 55.0 |"  # methods in canonical order
    assert lines[3] == "| act | — | 20.0 ± 0.0 (1) | — |"
    bar_plot(collect(tmp_path), tmp_path / "plot.png")
    assert (tmp_path / "plot.png").stat().st_size > 1000


def test_report_has_a_subtask_progress_table(tmp_path: Path) -> None:
    _cell(tmp_path, "skillret", "cook", 0, 0.0, subgoals=0.25)
    _cell(tmp_path, "skillret", "cook", 1, 0.0, subgoals=0.75)
    _cell(tmp_path, "act", "cook", 0, 0.0)  # summarised before progress was recorded
    report = markdown_report(collect(tmp_path), {})
    success, progress = report.split("### Subtask progress")
    assert "| skillret | 0.0 ± 0.0 (2) | 0.0 |" in success
    assert "| skillret | 50.0 ± 25.0 (2) | 50.0 |" in progress and "| act | — | — |" in progress


def test_heldout_table_is_the_final_checkpoints_mean_over_seeds(tmp_path: Path) -> None:
    def score(method: str, task: str, seed: int, final: tuple[float, float]) -> None:
        path = tmp_path / method / task / f"seed{seed}" / HELDOUT_FILE
        path.parent.mkdir(parents=True)
        rows = [{"step": 1000, "policy": 9.0, "oracle": 9.0}, {"step": 2000, "policy": final[0], "oracle": final[1]}]
        path.write_text(
            json.dumps({"method": method, "task": task, "seed": seed, "heldout_episodes": 10, "checkpoints": rows})
        )

    score("no_prior", "cook", 0, (0.4, 0.1))
    score("skillret", "cook", 0, (0.2, 0.1))
    score("skillret", "cook", 1, (0.3, 0.2))
    score("skillret", "breakfast", 0, (0.5, 0.25))
    report = markdown_report({}, collect(tmp_path, PUBLISHED_HELDOUT))
    table = report.split("### Held-out imitation error")[1]
    assert "| skillret | 0.500 (0.250) | 0.250 (0.150) | 0.375 |" in table  # step-1000 rows never count
    assert "| no_prior | — | 0.400 (0.100) | — |" in table
    assert "(step 2000), mean over 1/2 seeds" in table
    assert "Held-out" not in markdown_report({}, {})


def test_heldout_scores_trained_cells_once_and_publishes_only_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Unfinished cells are skipped, scores are reused until the evaluated checkpoints change, and a published cell
    of another output folder keeps its own score."""
    from lerobot_skillret.pipeline import heldout

    scored: list[Path] = []

    def fake_errors(checkpoint: Path, columns: object) -> dict[str, float]:
        scored.append(checkpoint)
        return {"policy": 0.5, "oracle": 0.1}

    monkeypatch.setattr(heldout, "imitation_errors", fake_errors)
    monkeypatch.setattr(heldout.EpisodeColumns, "from_dataset", lambda repo_id, root: [0] * 7)
    methods = ["skillret", "no_retrieval", "act"]
    cfg = PipelineConfig(
        output_dir=str(tmp_path / "out"),
        tasks=["cook"],
        methods=methods,
        seeds=[0, 1],
        baselines={"act": TrainSpec()},
        eval=EvalSpec(max_checkpoints=2),
    )
    plan, results = Plan(cfg), tmp_path / "results"
    runner = StageRunner(plan.root)
    monkeypatch.setattr(runner, "run", lambda stage: stage.output.mkdir(parents=True, exist_ok=True))

    def train(cell: Cell, steps: list[int], output_dir: Path) -> None:
        for step in steps:
            (plan.train_dir(cell) / "checkpoints" / f"{step:06d}" / "pretrained_model").mkdir(parents=True)
        published = plan.published_dir(results, cell)
        published.mkdir(parents=True)
        (published / "cell.json").write_text(json.dumps({"output_dir": str(output_dir)}))

    ours, theirs, unfinished = Cell("skillret", "cook", 0), Cell("no_retrieval", "cook", 0), Cell("skillret", "cook", 1)
    train(ours, [500, 1000], plan.root)
    train(theirs, [1000], tmp_path / "elsewhere")
    train(Cell("act", "cook", 0), [1000], plan.root)  # a baseline: nothing to score
    heldout.run_heldout(plan, runner, results)
    assert len(scored) == 3 and not plan.heldout_path(unfinished).exists()
    assert plan.heldout_path(ours).parent.parent.parent == plan.root / "heldout" / "seed7_n10"
    record = json.loads((plan.published_dir(results, ours) / HELDOUT_FILE).read_text())
    assert [r["step"] for r in record["checkpoints"]] == [500, 1000] and record["frames"] == 7
    assert not (plan.published_dir(results, theirs) / HELDOUT_FILE).exists()

    heldout.run_heldout(plan, runner, results)  # nothing changed: nothing rescored
    assert len(scored) == 3
    (plan.train_dir(ours) / "checkpoints" / "001500" / "pretrained_model").mkdir(parents=True)
    heldout.run_heldout(plan, runner, results)  # evaluated checkpoints are now 1000 and 1500
    assert len(scored) == 5
    assert [r["step"] for r in json.loads(plan.heldout_path(ours).read_text())["checkpoints"]] == [1000, 1500]


def test_best_checkpoint_ties_go_to_higher_progress(tmp_path: Path) -> None:
    """Seed C.3 picks the best success rate; with every checkpoint at 0% the one that got further counts."""
    cfg = PipelineConfig(output_dir=str(tmp_path), tasks=["cook"], methods=["no_retrieval"], seeds=[0])
    plan, cell = Plan(cfg), Cell("no_retrieval", "cook", 0)
    for step, progress in [(500, 0.5), (1000, 0.25)]:
        (plan.train_dir(cell) / "checkpoints" / str(step) / "pretrained_model").mkdir(parents=True)
        overall = {"pc_success": 0.0, "avg_max_reward": progress, "n_episodes": 10}
        info = plan.eval_dir(cell, step) / "eval_info.json"
        info.parent.mkdir(parents=True)
        info.write_text(json.dumps({"overall": overall}))
    summary = summarise_cell(plan, cell, train_seconds=1.0, eval_seconds=2.0)
    assert (summary["best_step"], summary["success"], summary["subgoals"]) == (500, 0.0, 0.5)


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_failed_shared_stage_stops_the_run_and_is_never_retried(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, jobs: int
) -> None:
    """Cells waiting for a shared stage that fails are cancelled, not re-run it; the stage's own error surfaces."""
    from lerobot_skillret.pipeline import run as run_mod

    counter = tmp_path / "runs.txt"
    shared = writer_stage(tmp_path, "shared", sleep=0.5, fail=True)
    shared.command[-1] = f"open({str(counter)!r}, 'a').write('x')\n" + shared.command[-1]
    started: list[Cell] = []

    def fake_run_cell(plan: Plan, runner: StageRunner, cell: Cell, results_dir: Path | None) -> None:
        for stage in run_mod.prerequisites(plan, cell):
            runner.run(stage)
        started.append(cell)

    monkeypatch.setattr(run_mod, "prerequisites", lambda plan, cell: [shared])
    monkeypatch.setattr(run_mod, "run_cell", fake_run_cell)
    cfg = PipelineConfig(output_dir=str(tmp_path / "out"), tasks=["breakfast", "cook"], methods=["skillret"])
    with pytest.raises(RuntimeError, match="stage shared failed"):
        run_mod.run_jobs(Plan(cfg), StageRunner(tmp_path / "out"), None, jobs)
    assert counter.read_text() == "x" and started == [] and not shared.output.exists()
