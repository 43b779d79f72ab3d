"""`relative_positions`: object minus gripper positions, their statistics, and where the config refuses them."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from lerobot.configs.types import NormalizationMode
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE
from policy_fixtures import PRIOR_REPO, build_policy, tiny_config, training_batch
from synthetic import make_synthetic_dataset

from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

pytestmark = pytest.mark.usefixtures("one_thread")

STATE, ENV = OBS_STATE, OBS_ENV_STATE
TRIPLE = slice(1, 4)  # the synthetic env state has 5 columns: one triple at 1, two absolute columns around it


@pytest.fixture(scope="module")
def prior_root(tmp_path_factory) -> Path:
    return make_synthetic_dataset(tmp_path_factory.mktemp("prior") / "ds", PRIOR_REPO, num_episodes=4, seed=0)


def all_frames(root: Path) -> dict[str, torch.Tensor]:
    data = LeRobotDataset(PRIOR_REPO, root=root).hf_dataset.with_format("torch")
    return {key: torch.stack(list(data[key])) for key in (STATE, ENV)}


def test_a_translated_scene_reads_the_same_relative_positions(prior_root):
    """Moving gripper and object together leaves the relative triple as it was; the absolute columns move."""
    policy = build_policy(tiny_config(relative_positions=(1,)), PRIOR_REPO, prior_root)
    raw = training_batch(policy.config, PRIOR_REPO, prior_root)
    moved = dict(raw)
    shift = torch.tensor([0.3, -0.2, 0.5])
    moved[STATE] = raw[STATE].clone()
    moved[STATE][..., :3] += shift
    moved[ENV] = raw[ENV].clone()
    moved[ENV][..., TRIPLE] += shift
    before, after = policy._window(raw), policy._window(moved)
    assert torch.allclose(before[ENV][..., TRIPLE], after[ENV][..., TRIPLE], atol=1e-5)
    assert not torch.allclose(before[STATE][..., :3], after[STATE][..., :3])
    # the same translation with absolute positions moves the object's columns
    absolute = build_policy(tiny_config(), PRIOR_REPO, prior_root)
    assert not torch.allclose(absolute._window(raw)[ENV][..., TRIPLE], absolute._window(moved)[ENV][..., TRIPLE])


@pytest.mark.parametrize("mode", [NormalizationMode.MEAN_STD, NormalizationMode.MIN_MAX])
def test_relative_positions_are_normalised_by_their_own_statistics(prior_root, mode):
    """Over the whole dataset the normalised relative triple has mean 0 (MEAN_STD: exact for a difference) and a
    unit-order spread, or lies inside [-1, 1] (MIN_MAX: the difference's bounds), like every absolute column."""
    mapping = {"STATE": mode, "ENV": mode, "ACTION": NormalizationMode.MEAN_STD, "VISUAL": NormalizationMode.IDENTITY}
    policy = build_policy(
        tiny_config(relative_positions=(1,), skill_normalization_mapping=mapping), PRIOR_REPO, prior_root
    )
    assert policy.low_dim_keys == [ENV, STATE]  # so the environment state's columns come first
    relative = policy.low_dim_features(all_frames(prior_root))[:, TRIPLE]
    if mode is NormalizationMode.MEAN_STD:
        assert torch.allclose(relative.mean(dim=0), torch.zeros(3), atol=1e-4)
        assert ((relative.std(dim=0) > 0.3) & (relative.std(dim=0) < 3)).all()
    else:
        assert relative.min() >= -1 - 1e-5 and relative.max() <= 1 + 1e-5


@pytest.mark.parametrize(
    ("starts", "message"),
    [((3,), "out of range: \\[3\\]"), ((-1,), "out of range"), ((0, 2), "overlapping: \\[2\\]")],
)
def test_triples_outside_the_environment_state_are_refused(prior_root, starts, message):
    with pytest.raises(ValueError, match=message):
        build_policy(tiny_config(relative_positions=starts), PRIOR_REPO, prior_root)


def test_stage2_keeps_the_stage1_choice(prior_root, tmp_path):
    """The statistics and weights of stage 1 read positions one way: a stage-2 override is refused at load."""
    folder = tmp_path / "stage1"
    build_policy(tiny_config(relative_positions=(1,)), PRIOR_REPO, prior_root).save_pretrained(folder)
    stage1 = SkillRetPolicy.from_pretrained(folder)
    assert stage1.config.relative_positions == (1,)
    config = tiny_config(stage="policy")
    config.input_features, config.output_features = stage1.config.input_features, stage1.config.output_features
    with pytest.raises(ValueError, match=r"trained with relative_positions=\[1\], this run asks for \[\]"):
        SkillRetPolicy.from_pretrained(folder, config=config)


def test_relative_positions_need_the_gripper_state(tmp_path):
    root = make_synthetic_dataset(tmp_path / "ds", PRIOR_REPO, num_episodes=1, state_dim=2, seed=0)
    with pytest.raises(ValueError, match=r"needs `observation.state` \(the end effector"):
        build_policy(tiny_config(relative_positions=(0,)), PRIOR_REPO, root)


def test_the_documented_kitchen_list_is_every_movables_position():
    """configs/README.md gives users the kitchen's list; it must follow the observation layout."""
    from lerobot_skillret.kitchen.layout import MOVABLES
    from lerobot_skillret.kitchen.observations import ENV_STATE_NAMES

    starts = [ENV_STATE_NAMES.index(f"{name}_x") for name in MOVABLES]
    assert ENV_STATE_NAMES[starts[0] : starts[0] + 3] == [f"{MOVABLES[0]}_{c}" for c in "xyz"]
    documented = (Path(__file__).resolve().parents[1] / "configs" / "README.md").read_text()
    assert f"--policy.relative_positions=[{','.join(map(str, starts))}]" in documented
