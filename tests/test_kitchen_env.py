"""Kitchen gym envs: gymnasium's env checker per task, light registration, features shared with the EnvConfig."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.env_config import PandaKitchenEnv
from lerobot_skillret.kitchen.registration import gym_id, register_envs
from lerobot_skillret.kitchen.tasks import TASKS

os.environ.setdefault("MUJOCO_GL", "egl")


def test_registration_and_env_config_do_not_import_the_simulator():
    code = (
        "import sys; import lerobot_skillret.kitchen.env_config as c; from lerobot_skillret.kitchen import registration;"
        "registration.register_envs(); import gymnasium as gym;"
        "assert all(registration.gym_id(t) in gym.registry for t in ('breakfast', 'cleaning_up'));"
        "assert 'robosuite' not in sys.modules and 'mujoco' not in sys.modules, 'heavy import'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.slow
@pytest.mark.parametrize("task", sorted(TASKS))
def test_check_env_passes(task):
    register_envs()
    env = gym.make(gym_id(task))
    check_env(env.unwrapped, skip_render_check=True)
    inner = env.unwrapped
    assert inner._max_episode_steps == TASKS[task].max_steps and inner.task == task and inner.task_description
    env.close()


@pytest.mark.slow
def test_cameras_success_flag_and_features_match_env_config():
    register_envs()
    env = gym.make(gym_id("breakfast"), cameras=("agentview", "eye_in_hand"), episode_length=3)
    obs, info = env.reset(seed=1)
    assert info["is_success"] is False
    cfg = PandaKitchenEnv(task="breakfast", cameras=("agentview", "eye_in_hand"))
    flat = {"agent_pos": obs["agent_pos"], "environment_state": obs["environment_state"]}
    flat.update({f"pixels/{k}": v for k, v in obs["pixels"].items()})
    assert {k: tuple(v.shape) for k, v in flat.items()} == {
        k: f.shape for k, f in cfg.features.items() if k != "action"
    }
    assert obs["pixels"]["agentview"].dtype == np.uint8 and obs["pixels"]["agentview"].std() > 0
    for _ in range(3):
        obs, _reward, terminated, truncated, info = env.step(np.zeros(7, dtype=np.float32))
        assert type(info["is_success"]) is bool
    assert truncated and not terminated
    frame = env.render()
    assert frame.shape == (256, 256, 3) and env.unwrapped.metadata["render_fps"] > 0
    # the env config maps env keys onto the dataset keys the generator writes
    assert set(cfg.features_map.values()) - {"action"} <= set(O.dataset_features(("agentview", "eye_in_hand")))
    env.close()


def test_reset_is_reproducible_by_seed():
    register_envs()
    env = gym.make(gym_id("cook"))
    a, _ = env.reset(seed=7)
    b, _ = env.reset(seed=7)
    c, _ = env.reset(seed=8)
    assert np.array_equal(a["environment_state"], b["environment_state"])
    assert not np.array_equal(a["environment_state"], c["environment_state"])
    env.close()


def test_reward_is_the_fraction_of_goals_met():
    """Replaying a scripted demo through the env: the reward climbs 0 -> 1/3 -> 2/3 -> 1, and 1 only on success."""
    from lerobot_skillret.kitchen.expert import run_expert
    from lerobot_skillret.kitchen.gym_env import KitchenEnv
    from lerobot_skillret.kitchen.primitives import Driver

    env = KitchenEnv("breakfast")
    env.reset(seed=3)
    actions: list[np.ndarray] = []
    driver = Driver(env.scene, np.random.default_rng(0), on_step=lambda action, _label: actions.append(action))
    assert run_expert(driver, env._task)
    env.reset(seed=3)
    rewards, chains, terminated = [], [], False
    for action in actions:
        _obs, reward, terminated, _truncated, info = env.step(action)
        rewards.append(reward)
        chains.append(info["in_a_row"])
        if terminated:
            break
    assert terminated and info["is_success"] and rewards[-1] == 1.0
    assert sorted(set(rewards)) == pytest.approx([0.0, 1 / 3, 2 / 3, 1.0])
    assert all(r < 1.0 for r in rewards[:-1])
    assert chains == [round(3 * r) for r in rewards]  # the expert completes the goals in their listed order
    env.close()


def test_in_a_row_stops_at_the_first_unmet_goal():
    """CALVIN's chain length: goals met at reset are skipped, a later goal met without the earlier one counts 0."""
    from lerobot_skillret.kitchen.predicates import Predicate
    from lerobot_skillret.kitchen.tasks import Step, Task

    def fixed(name: str, value: bool) -> Predicate:
        return Predicate(name, lambda _scene: value)

    def chain(now: tuple[bool, ...], at_reset: tuple[bool, ...]) -> int:
        goals = tuple(fixed(f"g{i}", v) for i, v in enumerate(now))
        return Task("t", "", goals, {}, 10, (Step("toggle", ("light", "on")),)).in_a_row(None, at_reset)

    assert chain((True, True, False), (False, False, False)) == 2
    assert chain((False, True, True), (False, False, False)) == 0
    assert chain((True, True, True), (False, True, False)) == 2  # the goal met at reset is not counted
    assert chain((False, False), (False, False)) == 0


def test_goals_met_at_reset_earn_no_progress():
    """cook starts with the pan on the stove: standing still scores 0, not 1/5."""
    from lerobot_skillret.kitchen.gym_env import KitchenEnv

    env = KitchenEnv("cook")
    env.reset(seed=0)
    assert env._task.goals_met(env.scene) == (False, False, False, True, False)
    assert env.step(np.zeros(7, dtype=np.float32))[1] == 0.0
    env.close()


def test_render_stride_reuses_frames_between_renders():
    from lerobot_skillret.kitchen.gym_env import KitchenEnv

    with pytest.raises(ValueError, match="render_stride"):
        KitchenEnv("breakfast", render_stride=0)
    env = KitchenEnv("breakfast", render_stride=3)
    env.reset(seed=0)
    first = env.render()
    env.step(np.zeros(7, dtype=np.float32))
    assert env.render() is first  # step 1: the cached frame
    env.step(np.zeros(7, dtype=np.float32))
    env.step(np.zeros(7, dtype=np.float32))
    assert env.render() is not first  # step 3: a fresh frame
    assert PandaKitchenEnv(render_stride=3).gym_kwargs["render_stride"] == 3
    env.close()


def test_discrete_gripper_turns_a_small_command_into_a_hold():
    """The fingers integrate their command: a learner's +0.2 where the demonstrations say 0 (hold) closes them
    step by step (on an object just released, in the bread chains); `discrete_gripper` rounds it to the hold."""
    from lerobot_skillret.kitchen.gym_env import KitchenEnv
    from lerobot_skillret.kitchen.primitives import CLOSED, OPEN

    assert {np.round(level) for level in (OPEN, 0.0, CLOSED)} == {OPEN, 0.0, CLOSED}  # the expert's own commands
    drift = np.zeros(7)
    drift[-1] = 0.2
    moved = {}
    for discrete in (False, True):
        env = KitchenEnv("bread_on_plate", discrete_gripper=discrete)
        env.reset(seed=0)
        start = env.scene.gripper_qpos()
        for _ in range(10):
            env.step(drift)
        moved[discrete] = float(np.abs(env.scene.gripper_qpos() - start).max())
        env.close()
    assert moved[False] > 0.01 and moved[True] < 0.001, moved  # (a hold still settles the fingers a little)
    assert PandaKitchenEnv().gym_kwargs["discrete_gripper"] is True  # the default, for every policy
    assert PandaKitchenEnv(discrete_gripper=False).gym_kwargs["discrete_gripper"] is False
    assert KitchenEnv("bread_on_plate").discrete_gripper


def test_lerobots_make_env_path_builds_the_kitchen():
    """LeRobot 0.6's own path: `make_env_config` + `make_env` go through `PandaKitchenEnv.create_envs`."""
    from lerobot.envs.factory import make_env, make_env_config, make_env_pre_post_processors

    cfg = make_env_config("panda_kitchen", task="cook", episode_length=5)
    envs = make_env(cfg, n_envs=2)
    vector = envs["panda_kitchen"][0]
    try:
        assert vector.num_envs == 2 and vector.call("task") == ("cook", "cook")
        obs, _ = vector.reset(seed=3)
        assert obs["agent_pos"].shape == (2, len(O.STATE_NAMES))
        assert vector.call("_max_episode_steps") == (5, 5)
    finally:
        vector.close()
    pre, post = make_env_pre_post_processors(cfg, policy_cfg=None)
    assert len(pre.steps) == len(post.steps) == 0  # the kitchen emits LeRobot's observation layout already


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("task", "no_such_task", "Unknown panda_kitchen task 'no_such_task'. Pass --env.task=<one of"),
        ("episode_length", 0, "--env.episode_length must be >= 1"),
        ("render_stride", 0, "--env.render_stride must be >= 1"),
        ("image_size", 0, "--env.image_size must be >= 1 pixel"),
        ("cameras", ("agentviw",), "--env.cameras: unknown camera(s) ['agentviw']"),
        ("fps", 5, "--env.fps is fixed: the kitchen runs at 20 Hz"),
    ],
)
def test_env_config_refuses_bad_values(field, value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        PandaKitchenEnv(**{field: value})


def test_gym_make_checks_its_options_as_the_env_config_does():
    """episode_length=0 used to mean the task's own length and -3 a one-step episode; a bare camera name
    (`--env.cameras=agentview`) was split into letters."""
    for length in (0, -3):
        with pytest.raises(ValueError, match=f"episode_length must be >= 1.*got {length}"):
            gym.make(gym_id("open_drawer"), episode_length=length)
    assert PandaKitchenEnv(cameras="agentview").cameras == ("agentview",)


@pytest.mark.slow
def test_lerobot_eval_names_an_unknown_task():
    """Before, LeRobot said "Package 'gym_panda_kitchen' not found. Please install it"."""
    result = subprocess.run(
        [
            str(Path(sys.executable).parent / "lerobot-eval"),
            "--env.type=panda_kitchen",
            "--env.task=no_such_task",
            "--policy.path=unused",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    assert result.returncode != 0
    assert "Unknown panda_kitchen task 'no_such_task'" in result.stderr and "not found" not in result.stderr


def test_item_geoms_take_their_sizes_from_layout():
    """layout.ITEMS is the one source of item sizes: the simulated geoms match it (the grasp heights depend on it)."""
    import mujoco

    from lerobot_skillret.kitchen import layout
    from lerobot_skillret.kitchen.gym_env import KitchenEnv

    env = KitchenEnv("bread_on_plate")
    model = env.scene.sim.model
    for name, spec in layout.ITEMS.items():
        geom = model.geom_name2id(f"{name}_geom")
        hx, hy, hz = spec.half
        cylinder = model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_CYLINDER  # its size is (radius, half-height)
        expected = [hx, hz, 0.0] if cylinder else [hx, hy, hz]
        size = model.geom_size[geom]
        assert np.allclose(size, expected), (name, size, expected)
    env.close()


def test_an_item_resting_on_the_plate_neither_sinks_nor_spins():
    """A box on a cylinder got one contact point: the bread sank ~5 mm into the plate and spun there (180 degrees in
    ~250 steps), an orientation play data never shows (the prior's skills read it 100 stds out of range)."""
    from lerobot_skillret.kitchen import layout
    from lerobot_skillret.kitchen.gym_env import KitchenEnv
    from lerobot_skillret.kitchen.sampling import sample_poses
    from lerobot_skillret.kitchen.tasks import get_task

    env = KitchenEnv("breakfast")
    scene = env.scene
    rng = np.random.default_rng(0)
    poses, joints = sample_poses(get_task("breakfast"), rng)
    plate_x, plate_y = layout.FIXTURES["serving"]
    poses["bread"] = (plate_x, plate_y, layout.item_rest_z("bread") + 0.01, 0.0)
    scene.reset_to(poses, joints, rng)
    for _ in range(200):
        scene.step(np.zeros(7))
    w, _, _, z = scene.body_quat("bread")
    yaw = 2 * np.arctan2(z, w)
    plate = scene.sim.model.geom_name2id("plate")
    plate_top = scene.sim.data.geom_xpos[plate][2] + scene.sim.model.geom_size[plate][1]
    bottom = scene.body_pos("bread")[2] - layout.ITEMS["bread"].half[2]
    assert abs(yaw) < 0.01, f"the bread turned {yaw:.3f} rad on the plate"
    assert bottom > plate_top - 0.001, f"the bread sank {1e3 * (plate_top - bottom):.1f} mm into the plate"
    env.close()
