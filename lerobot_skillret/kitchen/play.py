"""Task-agnostic play: random sequences of primitives that are feasible in the current scene.

Scenes start from a random task's initial-state distribution (so play covers every fixture and object the
target tasks use); primitives run with action noise and waypoint jitter, and failed ones are kept.
"""

from __future__ import annotations

import numpy as np

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen import predicates as P
from lerobot_skillret.kitchen.primitives import Driver, OutOfSteps, run_primitive
from lerobot_skillret.kitchen.sampling import PlacementError
from lerobot_skillret.kitchen.tasks import MULTI_STEP, Step

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
    """The task whose initial-state distribution a play episode starts from: one of the seed's multi-step tasks,
    whose scenes hold every object and fixture state (tasks added later do not change the play data)."""
    scenes = sorted(MULTI_STEP, key=lambda task: task.name)  # by name: the order play data was generated with
    return scenes[rng.integers(len(scenes))]


def run_play(driver: Driver, rng: np.random.Generator) -> list[tuple[Step, bool]]:
    """Random feasible primitives until the driver's step budget is spent; returns (step, success) pairs."""
    log: list[tuple[Step, bool]] = []
    try:
        while True:
            options = feasible_steps(driver.scene)
            step = options[rng.integers(len(options))]
            try:
                ok = run_primitive(driver, step.primitive, *step.args)
            except PlacementError:  # no free spot to put the item down: a failed primitive, like any other
                ok = False
            log.append((step, ok))
    except OutOfSteps:
        return log
