"""End to end: tiny synthetic datasets + a tiny stage-1 checkpoint -> `skillret-retrieve` -> retrieval file, report."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from policy_fixtures import PRIOR_REPO, TARGET_REPO, build_policy, tiny_config
from synthetic import NUM_PRIMITIVES, make_synthetic_dataset

from lerobot_skillret.data.fingerprint import checkpoint_fingerprint, dataset_fingerprint
from lerobot_skillret.data.retrieval_file import RetrievalResult
from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler
from lerobot_skillret.retrieval import api
from lerobot_skillret.retrieval.api import retrieve
from lerobot_skillret.retrieval.cli import main
from lerobot_skillret.retrieval.report import retrieval_precision
from lerobot_skillret.retrieval.settings import RetrievalSettings

NAMES = [f"skill_{i}" for i in range(NUM_PRIMITIVES)]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    base = tmp_path_factory.mktemp("retrieval")
    prior = make_synthetic_dataset(base / "prior", PRIOR_REPO, num_episodes=6, seed=0)
    target = make_synthetic_dataset(base / "target", TARGET_REPO, num_episodes=3, seed=1)
    torch.manual_seed(0)
    policy = build_policy(tiny_config(), PRIOR_REPO, prior)
    checkpoint = base / "skills" / "pretrained_model"
    policy.save_pretrained(checkpoint)
    return {"prior": prior, "target": target, "checkpoint": checkpoint, "policy": policy.eval(), "base": base}


def cli_args(setup, output: Path, *extra: str) -> list[str]:
    return [
        "--checkpoint", str(setup["checkpoint"]),
        "--prior-repo-id", PRIOR_REPO, "--prior-root", str(setup["prior"]),
        "--target-repo-id", TARGET_REPO, "--target-root", str(setup["target"]),
        "--output", str(output), "--quiet", *extra,
    ]  # fmt: skip


def test_cli_writes_a_consistent_retrieval_file_and_report(setup, tmp_path):
    output, report = tmp_path / "ret.safetensors", tmp_path / "report"
    relevant = "primitive 0,primitive 2"  # the synthetic data does not name its primitives
    assert main(cli_args(setup, output, "--report-dir", str(report), "--relevant-primitives", relevant)) == 0
    result = RetrievalResult.load(output)
    prior_frames = len(EpisodeColumns.from_dataset(PRIOR_REPO, setup["prior"]))
    # N = 250,000 by default exceeds the prior: every frame is a candidate; K = round(r * candidates).
    assert result.settings["num_candidates"] == prior_frames
    assert len(result) == round(0.1 * prior_frames)
    assert result.settings["mode"] == "nearest" and result.settings["metric"] == "l2"
    result.check_compatible(
        prior_fingerprint=dataset_fingerprint(setup["prior"]),
        target_fingerprint=dataset_fingerprint(setup["target"]),
        checkpoint_fingerprint=checkpoint_fingerprint(setup["checkpoint"]),
    )
    with pytest.raises(ValueError, match="different target dataset"):
        result.check_compatible(target_fingerprint=dataset_fingerprint(setup["prior"]))

    # The stored latents are the encoder means of the windows at prior_index, and the stored distances are
    # their L2 distances to the nearest target window's latent (recomputed here independently).
    policy = setup["policy"]
    keys = [*policy.low_dim_keys, "action"]
    prior_sampler = WindowSampler(EpisodeColumns.from_dataset(PRIOR_REPO, setup["prior"]), 3, 4, keys)
    target_columns = EpisodeColumns.from_dataset(TARGET_REPO, setup["target"])
    target_sampler = WindowSampler(target_columns, 3, 4, keys)
    mean, _ = policy.encode_skill(dict(prior_sampler.gather(result.prior_index).items()))
    torch.testing.assert_close(result.latent, mean, rtol=1e-5, atol=1e-5)
    target_mean, _ = policy.encode_skill(dict(target_sampler.gather(torch.arange(len(target_columns))).items()))
    all_mean, _ = policy.encode_skill(dict(prior_sampler.gather(torch.arange(prior_frames)).items()))
    nearest = torch.cdist(all_mean.double(), target_mean.double()).amin(1)
    torch.testing.assert_close(result.distance.double(), nearest[result.prior_index], rtol=1e-4, atol=1e-5)
    assert set(result.prior_index.tolist()) == set(torch.sort(nearest).indices[: len(result)].tolist())

    summary = json.loads((report / "summary.json").read_text())
    assert summary["retrieved"] == len(result) and summary["candidates"] == prior_frames
    assert summary["cut"] == pytest.approx(float(result.distance.max()), rel=1e-5)
    assert len(summary["primitives"]) == NUM_PRIMITIVES
    assert sum(row["retrieved_share"] for row in summary["primitives"]) == pytest.approx(1.0)
    assert 0.0 <= summary["precision"]["retrieved"] <= 1.0
    for name in ("latents_pca.png", "distance_histogram.png", "primitive_shares.png"):
        assert (report / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # The report's precision equals the share computed by hand from the prior's labels.
    labels = EpisodeColumns.from_dataset(PRIOR_REPO, setup["prior"]).td["primitive_index"]
    picked = labels[result.prior_index]
    precision = summary["precision"]
    assert precision["retrieved"] == pytest.approx(float(((picked == 0) | (picked == 2)).double().mean()))
    assert precision["candidates"] == pytest.approx(float(((labels == 0) | (labels == 2)).double().mean()))


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (["--ablation", "none"], lambda n: 0),
        (["--mode", "all"], lambda n: n),
        (["--ablation", "random", "--seed", "3"], lambda n: round(0.1 * n)),
        (["--fraction", "0.5", "--metric", "kl", "--num-prior", "60", "--num-target", "20"], lambda n: 30),
    ],
)
def test_modes_and_options(setup, tmp_path, extra, expected):
    output = tmp_path / "ret.safetensors"
    assert main(cli_args(setup, output, *extra)) == 0
    result = RetrievalResult.load(output)
    prior_frames = len(EpisodeColumns.from_dataset(PRIOR_REPO, setup["prior"]))
    assert len(result) == expected(prior_frames)
    assert len(set(result.prior_index.tolist())) == len(result)
    assert result.latent.shape == (len(result), 8)


def test_api_defaults_come_from_the_checkpoint(setup, tmp_path):
    checkpoint = tmp_path / "ckpt"
    shutil.copytree(setup["checkpoint"], checkpoint)
    config = json.loads((checkpoint / "config.json").read_text())
    config.update(retrieval_fraction=0.2, retrieval_num_target=10)
    (checkpoint / "config.json").write_text(json.dumps(config))
    result = retrieve(checkpoint, PRIOR_REPO, setup["prior"], TARGET_REPO, setup["target"], progress=False)
    assert result.settings["fraction"] == 0.2 and result.settings["num_target_windows"] == 10
    assert len(result) == round(0.2 * result.settings["num_candidates"])
    override = retrieve(
        checkpoint,
        PRIOR_REPO,
        setup["prior"],
        TARGET_REPO,
        setup["target"],
        settings=RetrievalSettings(fraction=0.05),
        progress=False,
    )
    assert override.settings["fraction"] == 0.05


def test_bad_inputs_have_clear_errors(setup, tmp_path, capsys, monkeypatch):
    output = tmp_path / "ret.safetensors"

    def fails(args: list[str], match: str) -> None:
        with pytest.raises(SystemExit) as exit_info:
            main(args)
        assert exit_info.value.code == 2
        assert match in capsys.readouterr().err

    missing = cli_args(setup, output)
    missing[1] = str(tmp_path / "nowhere")
    fails(missing, "does not exist")
    missing[1] = str(setup["checkpoint"] / "config.json")
    fails(missing, "config.json is a file, not a checkpoint folder")
    run = tmp_path / "run"
    shutil.copytree(setup["checkpoint"], run / "checkpoints" / "last" / "pretrained_model")
    missing[1] = str(run)
    fails(missing, f"{run} is a training run's folder: pass its checkpoint {run}/checkpoints/last/pretrained_model")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "config.json").write_text(json.dumps({"type": "skillret"}))
    fails([*cli_args(setup, output)[:1], str(broken), *cli_args(setup, output)[2:]], "model.safetensors")
    other = tmp_path / "other"
    shutil.copytree(setup["checkpoint"], other)
    (other / "config.json").write_text(json.dumps({"type": "act"}))
    fails([*cli_args(setup, output)[:1], str(other), *cli_args(setup, output)[2:]], "`act` checkpoint")
    no_data = cli_args(setup, output)
    no_data[no_data.index("--target-root") + 1] = str(tmp_path / "no_dataset")
    fails(no_data, "No LeRobotDataset at")
    fails(cli_args(setup, output, "--fraction", "1.5"), "`fraction`=1.5 is invalid")
    fails(cli_args(setup, output, "--num-target", "0"), "M must be >= 1")
    fails(cli_args(setup, output, "--relevant-primitives", "pick,place"), "Unknown primitive name(s) ['pick', 'place']")
    with pytest.raises(SystemExit):
        main(cli_args(setup, output, "--num-prior", "lots"))
    assert "expected a number of windows or 'all'" in capsys.readouterr().err
    with monkeypatch.context() as patch:  # refused before the windows are encoded, the run's expensive part
        patch.setattr(api, "encode_windows", lambda *args, **kwargs: pytest.fail("encoded before refusing"))
        fails(cli_args(setup, output, "--fraction", "0.0001"), "retrieves no window (round(r * N) = 0)")
        a_file = tmp_path / "a_file"
        a_file.write_text("")
        fails(cli_args(setup, a_file / "ret.safetensors"), f"--output {a_file}/ret.safetensors: {a_file} is a file")
        report = ["--report-dir", str(a_file / "sub" / "report")]
        fails(cli_args(setup, output, *report), f"{a_file} is a file, not a folder")
    assert not output.exists()


def test_retrieval_precision():
    labels = torch.tensor([0, 1, 2, 2, 3])
    assert retrieval_precision(labels, ["skill_2"], NAMES) == pytest.approx(0.4)
    assert retrieval_precision(labels, ["skill_0", "skill_3"], NAMES) == pytest.approx(0.4)
    assert retrieval_precision(labels, [], NAMES) == 0.0
    with pytest.raises(ValueError, match="Unknown primitive name"):
        retrieval_precision(labels, ["skill_9"], NAMES)


@pytest.mark.slow
def test_console_script(setup, tmp_path):
    output = tmp_path / "ret.safetensors"
    script = Path(sys.executable).with_name("skillret-retrieve")
    done = subprocess.run([str(script), *cli_args(setup, output)], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert "retrieved" in done.stderr and len(RetrievalResult.load(output)) > 0


def test_help_explains_the_options():
    from lerobot_skillret.retrieval.cli import build_parser

    help_text = build_parser().format_help()
    assert "--num-prior" in help_text and "appendix A.4" in help_text and "--ablation random" in help_text


def test_help_shows_the_config_defaults(monkeypatch):
    """The defaults --help names are SkillRetConfig's (one source of truth), not numbers typed into the help."""
    from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
    from lerobot_skillret.retrieval import cli

    monkeypatch.setattr(SkillRetConfig, "retrieval_fraction", 0.37)
    monkeypatch.setattr(SkillRetConfig, "retrieval_num_target", 1234)
    help_text = " ".join(cli.build_parser().format_help().split())
    assert "config default 0.37" in help_text and "config default 1,234" in help_text


def test_cli_options_map_onto_settings():
    from lerobot_skillret.retrieval.cli import build_parser, settings_from_args

    def parse(*extra: str):
        base = ["--checkpoint", "c", "--prior-root", "p", "--target-root", "t", "--output", "o"]
        return settings_from_args(build_parser().parse_args([*base, *extra]))

    assert parse() == RetrievalSettings()
    assert parse("--ablation=random", "--seed=3") == RetrievalSettings(mode="random", seed=3)
    assert parse("--ablation", "large", "--fraction", "0.05").num_prior == "all"
    assert parse("--ablation", "nearest") == parse()
    flags = parse("--no-exact", "--num-prior", "250_000")
    assert (flags.exact, flags.num_prior) == (False, 250_000)


def test_a_kill_during_the_report_leaves_neither_report_nor_file(setup, tmp_path):
    """SIGKILL after the first figure: no retrieval file, no report, no 0-byte figure; the re-run cleans the
    killed run's staging folder and writes both."""
    output, report = tmp_path / "ret.safetensors", tmp_path / "report"
    args = cli_args(setup, output, "--report-dir", str(report))
    killer = (
        "import os, signal, sys; from lerobot_skillret.retrieval import report; from lerobot_skillret.retrieval.cli "
        "import main; save = report._save_figure\n"
        "def save_then_die(*a, **k):\n    save(*a, **k); os.kill(os.getpid(), signal.SIGKILL)\n"
        f"report._save_figure = save_then_die; sys.exit(main({args!r}))"
    )
    killed = subprocess.run([sys.executable, "-c", killer], env={**os.environ, "HF_HUB_OFFLINE": "1"})
    assert killed.returncode == -signal.SIGKILL
    assert not output.exists() and not report.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".report.tmp-")]  # SIGKILL skips cleanup

    assert main(args) == 0
    assert output.is_file() and (report / "summary.json").is_file()
    leftovers = [p.name for p in tmp_path.rglob("*") if p.name.startswith(".") or p.stat().st_size == 0]
    assert leftovers == []


def test_a_report_folder_holding_other_files_is_refused_and_left_intact(setup, tmp_path, capsys):
    """The report replaces its folder whole: pointing --report-dir at a folder of other files (the retrieval
    file's own, say) must stop before anything is written, and an earlier report may be replaced."""
    keep = tmp_path / "other.safetensors"
    keep.write_bytes(b"not mine")
    output = tmp_path / "ret.safetensors"
    with pytest.raises(SystemExit) as stop:
        main(cli_args(setup, output, "--report-dir", str(tmp_path)))
    assert stop.value.code == 2
    assert "already holds other files" in capsys.readouterr().err
    assert keep.read_bytes() == b"not mine" and not output.exists()

    report = tmp_path / "report"
    assert main(cli_args(setup, output, "--report-dir", str(report))) == 0
    assert main(cli_args(setup, output, "--report-dir", str(report))) == 0  # an earlier report is replaced
    assert (report / "summary.json").is_file() and keep.read_bytes() == b"not mine"


NO_GPU = "cuda" if not torch.cuda.is_available() else "tpu"


@pytest.mark.parametrize(
    ("device", "output_name", "named"),
    [
        ("gpu", "ret.safetensors", "Unknown device gpu"),  # was "the weights are truncated or corrupt"
        (NO_GPU, "ret.safetensors", "device"),  # was a raw driver RuntimeError
        (None, "", "is a folder: pass the retrieval file's path"),  # was a raw IsADirectoryError at the very end
    ],
)
def test_a_bad_device_or_output_is_one_line_naming_it(setup, tmp_path, capsys, device, output_name, named):
    with pytest.raises(SystemExit) as stop:
        main(cli_args(setup, tmp_path / output_name, *(["--device", device] if device else [])))
    assert stop.value.code == 2
    assert named in capsys.readouterr().err
