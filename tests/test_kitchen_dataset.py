"""Generated kitchen datasets: offline loading, features equal to the env's, replay parity, atomic writes."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from lerobot_skillret.data.labels import load_label_names
from lerobot_skillret.kitchen import generate as G
from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.primitives import PRIMITIVES
from lerobot_skillret.kitchen.tasks import TASKS

pytestmark = pytest.mark.slow


def _generate(root, *argv):
    G.main([*argv, "--root", str(root), "--workers", "0", "--seed", "5"])


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    os.environ["HF_HUB_OFFLINE"] = "1"
    base = tmp_path_factory.mktemp("kitchen")
    _generate(base / "demos", "demos", "--task", "breakfast", "--episodes", "2")
    _generate(base / "play", "play", "--episodes", "1", "--steps-per-episode", "120")
    return base


def _load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    meta = json.loads((root / "meta" / "info.json").read_text())
    return LeRobotDataset(meta.get("repo_id", "local/kitchen"), root=root)


def test_datasets_load_offline_with_the_env_layout(datasets):
    from lerobot_skillret.kitchen.env_config import PandaKitchenEnv

    cfg = PandaKitchenEnv(task="breakfast")
    for name in ("demos", "play"):
        ds = _load(datasets / name)
        assert ds.fps == cfg.fps and ds.num_frames > 0
        for env_key, feature in cfg.features.items():
            ds_key = cfg.features_map[env_key]
            assert tuple(ds.meta.features[ds_key]["shape"]) == feature.shape, ds_key
        assert ds.meta.features["observation.state"]["names"] == O.STATE_NAMES
        assert ds.meta.features["observation.environment_state"]["names"] == O.ENV_STATE_NAMES
        item = ds[0]
        assert item["observation.environment_state"].shape == (len(O.ENV_STATE_NAMES),)


def test_demos_succeed_and_play_is_labelled(datasets):
    demos = O.load_kitchen_meta(datasets / "demos")
    assert demos["task"] == "breakfast" and len(demos["episodes"]) == 2
    assert all(ep["success"] for ep in demos["episodes"])
    assert _load(datasets / "demos").meta.tasks.index[0] == TASKS["breakfast"].description
    play = O.load_kitchen_meta(datasets / "play")
    assert load_label_names(datasets / "play") == list(PRIMITIVES) and play["episodes"][0]["length"] == 120
    labels = np.asarray(_load(datasets / "play").hf_dataset[O.PRIMITIVE_KEY]).reshape(-1)
    assert labels.min() >= 0 and labels.max() < len(PRIMITIVES)
    counted = {name: int((labels == i).sum()) for i, name in enumerate(PRIMITIVES)}
    assert play["primitive_frames"] == counted and sum(counted.values()) == 120
    done = sum(entry[-1] == "True" for entry in play["episodes"][0]["primitives"])
    assert set(play["plan_step_calls"]) >= {"pick_place(milk, placemat_right)", "toggle(burner, on)"}
    assert sum(play["plan_step_calls"].values()) <= done  # successful calls only


def test_reset_to_a_recorded_initial_state_reproduces_the_first_frame(datasets):
    from lerobot_skillret.kitchen.gym_env import KitchenEnv

    meta = O.load_kitchen_meta(datasets / "demos")["episodes"][1]
    first = _load(datasets / "demos").hf_dataset.filter(lambda row: row["episode_index"] == 1)[0]
    env = KitchenEnv(task="breakfast")
    observation, _ = env.reset(seed=123, options={"initial_state": meta["initial_state"]})
    np.testing.assert_array_equal(observation["agent_pos"], np.asarray(first["observation.state"], np.float32))
    np.testing.assert_array_equal(
        observation["environment_state"], np.asarray(first["observation.environment_state"], np.float32)
    )
    assert env.unmet_goals() == [goal.name for goal in TASKS["breakfast"].goals]
    env.close()


def test_replay_of_recorded_actions_reproduces_success(datasets):
    from lerobot_skillret.kitchen.replay import episode_actions, replay_actions
    from lerobot_skillret.kitchen.scene import KitchenScene

    meta = O.load_kitchen_meta(datasets / "demos")
    actions = episode_actions(datasets / "demos")
    scene = KitchenScene()
    for ep in meta["episodes"]:
        initial = np.array(ep["initial_state"])
        assert replay_actions(scene, initial, actions[ep["episode_index"]], TASKS["breakfast"])
        # the recorded first observation is the restored state's observation
        scene.reset()
        scene.set_sim_state(initial)
        first = _load(datasets / "demos").hf_dataset.filter(lambda r, e=ep: r["episode_index"] == e["episode_index"])
        np.testing.assert_allclose(
            np.asarray(first[0]["observation.environment_state"]), O.environment_state(scene), atol=1e-6
        )


def test_generation_is_reproducible_and_atomic(datasets, tmp_path, monkeypatch):
    _generate(tmp_path / "again", "play", "--episodes", "1", "--steps-per-episode", "120")
    a = _load(datasets / "play").hf_dataset["action"]
    b = _load(tmp_path / "again").hf_dataset["action"]
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(SystemExit, match="already exists"):
        _generate(tmp_path / "again", "play", "--episodes", "1", "--steps-per-episode", "5")

    def boom(job):
        raise RuntimeError("simulated crash")

    monkeypatch.setattr(G, "run_episode", boom)
    with pytest.raises(RuntimeError, match="simulated crash"):
        _generate(tmp_path / "broken", "play", "--episodes", "1", "--steps-per-episode", "5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again"]


def test_cli_rejects_bad_input(tmp_path):
    with pytest.raises(SystemExit):
        G.main(["demos", "--task", "no_such_task", "--root", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="--episodes"):
        G.main(["play", "--episodes", "0", "--root", str(tmp_path / "x")])
