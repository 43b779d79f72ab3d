"""Task-agnostic play: random sequences of primitives that are feasible in the current scene.

Scenes start from a random built-in task's initial-state distribution (so play covers every fixture and object the
target tasks use, and the places where each task parks the objects it does not use); primitives run with action
noise and waypoint jitter, and failed ones are kept.

Each call first draws a primitive uniformly among those feasible now, then its arguments: drawing uniformly over
all (primitive, arguments) calls gave pick-and-place 77 % of the frames (one call per item and region) and left
the drawer, the switches and the vessels with 3-16 % together; `close_drawer` never ran in 16 episodes.

Half of the calls (PLAN_SHARE) are drawn that way among the feasible calls that some built-in task's plan makes
(food onto the plate or into the pan, a vessel onto the stove, a switch on): what a person playing in a kitchen
mostly does. Uniform arguments alone spread ~220 calls of a 32k-frame prior over ~50 pick-and-place calls: it held
no milk put right of the plate and no sausage put into the pan, two of the calibrated tasks' steps, so retrieval
had nothing to find for them. The set is every built-in task's, never one target's.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen import predicates as P
from lerobot_skillret.kitchen.primitives import Driver, OutOfSteps, run_primitive
from lerobot_skillret.kitchen.sampling import PlacementError
from lerobot_skillret.kitchen.tasks import BUILT_IN, Step

ITEM_REGIONS = {
    **{f: ("plate", "placemat_left", "placemat_right", "pan", "pot", "table") for f in layout.FOODS},
    **{b: ("drawer", "table", "shelf") for b in layout.BLOCKS},
}


def _reachable(scene, name: str) -> bool:
    x0, x1, y0, y1 = layout.WORK_AREA
    x, y, _ = scene.body_pos(name)
    return x0 < x < x1 and y0 < y < y1


def feasible_steps(scene) -> list[Step]:
    """Every primitive call that makes sense now (each region check mirrors what the primitive needs)."""
    drawer_open = P.drawer_open()(scene)
    vessels = [v for v in layout.VESSELS if _reachable(scene, v)]
    steps = [Step("close_drawer") if drawer_open else Step("open_drawer")]
    for switch, joint in P.SWITCH_JOINTS.items():
        steps.append(Step("toggle", (switch, "off" if scene.joint(joint) > 0 else "on")))
    for item, regions in ITEM_REGIONS.items():
        if not _reachable(scene, item):
            continue
        for region in regions:
            if region in layout.VESSELS and region not in vessels:
                continue
            if region == "drawer" and not drawer_open:
                continue
            steps.append(Step("pick_place", (item, region)))
    stove_busy = any(P.vessel_on_stove(v)(scene) for v in vessels)
    for v in vessels:
        if P.vessel_on_stove(v)(scene):
            steps.append(Step("move_vessel", (v, "pan_table")))
        elif not stove_busy:
            steps.append(Step("move_vessel", (v, "stove")))
    return steps


def play_scene_task(rng: np.random.Generator):
    """The task whose initial-state distribution a play episode starts from: any built-in task (the ladder and
    the seed's multi-step tasks). Only multi-step scenes gave observations the ladder's scenes never match: a
    single-step task parks its unused objects elsewhere (the pot 13 stds from anything play had seen), which
    the skill model's observation encoders could not read. Tasks from plugins, and built-in tasks marked
    `play_scene=False` (their scene is another task's), do not change the play data."""
    scenes = sorted((task for task in BUILT_IN if task.play_scene), key=lambda task: task.name)
    return scenes[rng.integers(len(scenes))]


PLAN_SHARE = 0.5


def plan_steps() -> frozenset[Step]:
    """Every call some built-in task's plan makes (plugin tasks do not change the play data)."""
    return frozenset(step for task in BUILT_IN for step in task.plan)


def draw_step(options: list[Step], rng: np.random.Generator, plan: frozenset[Step] = frozenset()) -> Step:
    """With probability PLAN_SHARE only the calls in `plan` are options (when any is); then a primitive uniformly
    among the options, and one of its calls uniformly."""
    planned = [step for step in options if step in plan]
    if planned and rng.random() < PLAN_SHARE:
        options = planned
    primitives = sorted({step.primitive for step in options})
    chosen = primitives[rng.integers(len(primitives))]
    calls = [step for step in options if step.primitive == chosen]
    return calls[rng.integers(len(calls))]


def run_play(driver: Driver, rng: np.random.Generator) -> list[tuple[Step, bool]]:
    """Random feasible primitives until the driver's step budget is spent; returns (step, success) pairs."""
    log: list[tuple[Step, bool]] = []
    plan = plan_steps()
    try:
        while True:
            step = draw_step(feasible_steps(driver.scene), rng, plan)
            try:
                ok = run_primitive(driver, step.primitive, *step.args)
            except PlacementError:  # no free spot to put the item down: a failed primitive, like any other
                ok = False
            log.append((step, ok))
    except OutOfSteps:
        return log


def plan_coverage(logs: list[list[tuple]]) -> dict[str, int]:
    """Successful calls of each built-in plan step in play episodes' logs ((primitive, *args, success) entries):
    what a prior holds for each sub-skill the tasks need, by name, fewest first."""
    done = Counter(Step(entry[0], tuple(entry[1:-1])) for log in logs for entry in log if entry[-1])
    counts = {step: done[step] for step in plan_steps()}
    ordered = sorted(counts, key=lambda step: (counts[step], step.primitive, step.args))
    return {f"{step.primitive}({', '.join(step.args)})": counts[step] for step in ordered}
