"""The package installs as a LeRobot plugin: light import, stock CLI discovery, config validation."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_skillret.policy.configuration_skillret import SkillRetConfig

BIN = Path(sys.executable).parent


def test_import_is_light() -> None:
    """LeRobot imports every plugin at CLI start-up: it must not pull in the simulator."""
    code = (
        "import lerobot_skillret, lerobot_policy_skillret, sys; "
        "heavy = [m for m in ('robosuite', 'mujoco') if m in sys.modules]; "
        "assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_lerobots_plugin_discovery_registers_both_types() -> None:
    """LeRobot's own discovery (`register_third_party_plugins`, what every lerobot CLI runs first), in a clean
    interpreter that never imports this package itself, registers `skillret` and `panda_kitchen`."""
    code = (
        "import sys; from lerobot.configs.policies import PreTrainedConfig; from lerobot.envs.configs import EnvConfig; "
        "from lerobot.utils.import_utils import register_third_party_plugins; "
        "assert 'skillret' not in PreTrainedConfig.get_known_choices(); "
        "register_third_party_plugins(); "
        "assert 'skillret' in PreTrainedConfig.get_known_choices(), 'policy type not registered'; "
        "assert 'panda_kitchen' in EnvConfig.get_known_choices(), 'env type not registered'; "
        "assert 'lerobot_policy_skillret' in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_stock_train_cli_lists_skillret_options() -> None:
    out = subprocess.run(
        [str(BIN / "lerobot-train"), "--policy.type=skillret", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    for option in (
        "--policy.horizon",
        "--policy.history",
        "--policy.kl_weight",
        "--policy.tc_weight",
        "--policy.retrieval_fraction",
        "--policy.stage",
    ):
        assert option in out, f"{option} missing from lerobot-train --help"


def test_defaults_are_the_papers() -> None:
    cfg = SkillRetConfig(device="cpu")
    assert (cfg.horizon, cfg.history, cfg.latent_dim) == (10, 10, 64)
    assert (cfg.encoder_lstm_hidden, cfg.decoder_lstm_hidden, cfg.policy_lstm_hidden) == (1000, 1000, 1000)
    assert cfg.encoder_mlp == cfg.decoder_mlp == cfg.prior_mlp == (1024, 1024) and cfg.tc_mlp == (128, 128)
    assert (cfg.kl_weight, cfg.tc_weight, cfg.retrieved_weight) == (1e-5, 1e-6, 1.0)
    assert (cfg.skill_lr, cfg.tc_lr, cfg.policy_lr) == (5e-4, 1e-4, 1e-3)
    assert (cfg.retrieval_num_prior, cfg.retrieval_num_target, cfg.retrieval_fraction) == (250_000, 2_500, 0.1)
    assert cfg.action_delta_indices == list(range(10))
    assert cfg.observation_delta_indices == list(range(10))  # stage 1 sees the window only
    policy_stage = SkillRetConfig(device="cpu", stage="policy")
    assert policy_stage.observation_delta_indices == list(range(-9, 10))  # F history frames + the window


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("horizon", 0),
        ("history", 0),
        ("retrieval_fraction", 0.0),
        ("retrieval_fraction", 1.5),
        ("kl_weight", -1.0),
        ("tc_weight", -1e-6),
        ("retrieved_weight", -0.1),
        ("policy_lr", 0.0),
        ("stage", "pretrain"),
        ("retrieval_metric", "cosine"),
        ("vision_backbone", "vit_b_16"),
        ("kl_weight", float("nan")),
        ("skill_lr", float("nan")),
        ("policy_obs_noise", float("nan")),
        ("encoder_mlp", (1024, 0)),
        ("retrieval_num_prior", 0),
    ],
)
def test_bad_values_name_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"`{field}`"):
        SkillRetConfig(device="cpu", **{field: value})


def test_decoder_policy_weight_needs_a_decoder_that_trains() -> None:
    with pytest.raises(ValueError, match=r"`decoder_policy_weight`.*finetune_skills=true"):
        SkillRetConfig(device="cpu", decoder_policy_weight=1.0, finetune_skills=False)


def test_a_prior_root_without_its_repo_id_is_refused_not_dropped() -> None:
    """prior_repo_id=None means "no prior data": with a prior_root set the user meant a prior."""
    with pytest.raises(ValueError, match=r"`prior_repo_id`.*prior_root=null"):
        SkillRetConfig(device="cpu", stage="policy", prior_root="data/play")
    SkillRetConfig(device="cpu", stage="policy", prior_root="data/play", prior_repo_id="local/play")


def test_stages_import_one_way_without_cycles() -> None:
    """The import-linter contracts in pyproject.toml (also run by `make lint`): data <- policy <- retrieval <-
    pipeline, the method never imports the kitchen, no module cycles."""
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        [str(Path(sys.executable).parent / "lint-imports"), "--no-cache"], cwd=root, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout[-3000:]
