"""Can a checkpoint's skill decoder execute a task's demonstrations when it is handed the right skills?

Each demonstration's initial state is restored in the kitchen env and, every H steps, the checkpoint's encoder
encodes the demonstration's own window at that time (the oracle latent); the closed-loop decoder executes it. High
success here and low success of the trained policy points at the latent policy; low success here points at the
skill model. On demonstrations that no run trained on (another generation seed) it measures whether stage 1 learned
skills that transfer to the target task. With `policy_every` a stage-2 checkpoint's latent policy chooses some of the
skills itself (every skill: the policy's own rollout from the demonstrations' initial states), which shows whether
its latents fail everywhere or only where it has to carry on from its own earlier choices. With `swap` each rollout
starts from one demonstration's initial state and executes another's latents: whether a skill latent means "pick the
fish" wherever the fish is, or replays one demonstration's motion. With `trace` every rollout also reports, at each
skill, the demonstration step nearest the robot's state and the sub-goals met so far: where a rollout leaves the
demonstration, stalls, or loops back to retry a step.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from lerobot.envs.utils import preprocess_observation

from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler
from lerobot_skillret.kitchen.gym_env import KitchenEnv
from lerobot_skillret.kitchen.observations import load_kitchen_meta
from lerobot_skillret.kitchen.tasks import get_task
from lerobot_skillret.pipeline.heldout import skill_starts
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy
from lerobot_skillret.retrieval.api import resolve_checkpoint


@dataclass
class OracleEpisode:
    episode_index: int
    length: int
    success: bool
    unmet: list[str]


@torch.no_grad()
def oracle_episode(
    policy: SkillRetPolicy,
    env: KitchenEnv,
    sampler: WindowSampler,
    first: int,
    length: int,
    initial_state: np.ndarray,
    slack: float,
    align: bool = False,
    policy_every: int = 0,
    trace: list[tuple[int, int]] | None = None,
) -> tuple[bool, list[str]]:
    """Oracle-skill rollout of the demonstration whose frames start at global index `first`; it may run `slack`
    times the demonstration's length (past its end it keeps executing the last window's skill).

    The latent is the demonstration's window at the rollout's step t (its clock), or with `align` the window, at
    most 3 H steps ahead of the previous one, whose first observation is closest to the robot's current one (its
    phase): a rollout that lags or leads the demonstration then still gets the skill for where it is. Every
    `policy_every`-th skill (0: none) is left to the latent policy (`select_action` picks it from the history).
    `trace`, if a list, gets one (nearest demonstration step, sub-goals met) pair per skill."""
    observation, _ = env.reset(options={"initial_state": initial_state})
    horizon, success, at = policy.config.horizon, False, 0
    unmet_at_reset = len(env.unmet_goals())
    policy.reset()
    for t in range(int(length * slack)):
        batch = preprocess_observation({key: value[None] for key, value in observation.items()})
        skill = t // horizon
        if trace is not None and t % horizon == 0:
            nearest = _closest_frame(policy, sampler, batch, first, 0, length - 1)
            trace.append((nearest, unmet_at_reset - len(env.unmet_goals())))
        if t % horizon == 0 and not (policy_every and skill % policy_every == policy_every - 1):
            at = _closest_frame(policy, sampler, batch, first, at, min(at + 3 * horizon, length - 1)) if align else t
            anchor = torch.tensor([first + min(at, length - 1)])
            policy.execute_skill(policy.encode_skill(sampler.gather(anchor))[0])
        observation, _, _, _, info = env.step(policy.select_action(batch)[0].numpy())
        if success := info["is_success"]:
            break
    return success, env.unmet_goals()


def _closest_frame(policy: SkillRetPolicy, sampler: WindowSampler, batch: dict, first: int, lo: int, hi: int) -> int:
    """The demonstration step in [lo, hi] whose normalised observation is nearest the current one (L2)."""
    frames = torch.arange(first + lo, first + hi + 1)
    demo = policy.low_dim_features(
        {k: sampler.columns.td[k].as_subclass(torch.Tensor)[frames] for k in policy.low_dim_keys}
    )
    now = policy.low_dim_features(batch)
    return lo + int((demo - now).norm(dim=-1).argmin())


def swapped(entries: list[dict], swap: int) -> list[tuple[dict, dict]]:
    """(initial state's demonstration, latents' demonstration) pairs: each demonstration with the one `swap` places
    further on, wrapping around (0: its own)."""
    return [(entry, entries[(i + swap) % len(entries)]) for i, entry in enumerate(entries)]


def oracle_success(
    checkpoint: Path,
    demos: Path,
    task: str,
    episodes: int | None = None,
    slack: float = 1.5,
    align: bool = False,
    policy_every: int = 0,
    swap: int = 0,
    discrete_gripper: bool = True,
    trace: bool = False,
    log=print,
) -> dict:
    """Oracle-skill success of `checkpoint` on the first `episodes` demonstrations of the dataset at `demos`, and
    the teacher-forced oracle action error on all of them (squared error summed over action dimensions, in the
    decoder's normalised units, at every window where a rollout picks a skill) and the same with other windows'
    skills (`shuffled`: how much the decoder hangs on its skill), and of the demos' mean action held constant (the
    scale of both in this checkpoint's units). `policy_every`: see
    `oracle_episode` (needs a stage-2 checkpoint: a stage-1 latent policy is untrained). `swap` > 0: rollout i
    starts from demonstration i's initial state but executes the latents of demonstration i + swap (of the first
    `episodes`, wrapping around). `discrete_gripper`: the env rounds the gripper command to open / hold / close (its
    default). `trace`: log each rollout's nearest demonstration step and sub-goals met at every skill."""
    hint = "Pass a skillret `pretrained_model` folder (stage 1 or 2), e.g. <run>/checkpoints/last/pretrained_model."
    checkpoint = resolve_checkpoint(checkpoint, hint, needs="the oracle runs a skillret skill decoder")
    get_task(task)  # an unknown task is named before the model and the demos load
    policy = SkillRetPolicy.from_pretrained(checkpoint).eval()
    config = policy.config
    if policy_every and config.stage != "policy":
        raise ValueError(f"policy_every={policy_every} needs a stage-2 checkpoint; {checkpoint} is `{config.stage}`.")
    columns = EpisodeColumns.from_dataset(f"local/{demos.name}", demos)
    sampler = WindowSampler(columns, history=config.history, horizon=config.horizon)
    errors = policy.imitation_error(sampler.gather(skill_starts(columns, config.horizon)))
    meta = load_kitchen_meta(demos)["episodes"][:episodes]
    episode_index = columns.td["episode_index"].as_subclass(torch.Tensor).numpy()
    episode_end = columns.td["episode_end"].as_subclass(torch.Tensor).numpy()
    env, rows = KitchenEnv(task=task, discrete_gripper=discrete_gripper), []
    try:
        for start, source in swapped(meta, swap):
            first = int(np.flatnonzero(episode_index == source["episode_index"])[0])
            length = int(episode_end[first]) - first
            steps: list[tuple[int, int]] | None = [] if trace else None
            success, unmet = oracle_episode(
                policy,
                env,
                sampler,
                first,
                length,
                np.asarray(start["initial_state"]),
                slack,
                align,
                policy_every,
                steps,
            )
            rows.append(OracleEpisode(start["episode_index"], length, success, unmet))
            latents = f", latents of demo {source['episode_index']}" if swap else ""
            log(f"  demo {start['episode_index']}{latents}: {length} steps, success={success}, unmet={unmet}")
            if steps:
                log(f"    nearest demo step per skill: {' '.join(str(step) for step, _ in steps)}")
                log(f"    sub-goals met per skill:     {' '.join(str(met) for _, met in steps)}")
    finally:
        env.close()
    goals = len(get_task(task).goals)
    return {
        "episodes": len(rows),
        "success": sum(r.success for r in rows) / max(len(rows), 1),
        "goals_met": 1 - sum(len(r.unmet) for r in rows) / max(len(rows) * goals, 1),
        "oracle_action_error": float(errors["oracle"].mean()),
        "shuffled_action_error": float(errors["shuffled"].mean()),
        "mean_action_error": float(errors["mean_action"].mean()),
        "failures": {r.episode_index: r.unmet for r in rows if not r.success},
    }
