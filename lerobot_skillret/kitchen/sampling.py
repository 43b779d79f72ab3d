"""Initial-state sampling: turn a task's `init` spec into object poses with a seeded rng.

A rejection sampler with gripper clearance (centre distance >= both spacing radii + CLEARANCE) keeps objects
graspable; robosuite's UniformRandomSampler only separates object radii and knows nothing of fixtures.
"""

from __future__ import annotations

import numpy as np

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen.tasks import Task

Pose = tuple[float, float, float, float]  # x, y, z, yaw
CLEARANCE = 0.03
ITEM_YAW = 0.15
MAX_TRIES = 200


class PlacementError(RuntimeError):
    pass


def free_spot(
    rng: np.random.Generator, regions: tuple[str, ...], radius: float, taken: list[tuple[float, float, float]]
) -> tuple[float, float]:
    """A uniformly random (x, y) in one of `regions` that keeps clearance from `taken` (x, y, radius) circles."""
    for _ in range(5 * MAX_TRIES):
        x0, x1, y0, y1 = layout.REGIONS[regions[rng.integers(len(regions))]]
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if all(np.hypot(x - tx, y - ty) >= radius + tr + CLEARANCE for tx, ty, tr in taken):
            return float(x), float(y)
    raise PlacementError(f"no free spot of radius {radius} in {regions} after {5 * MAX_TRIES} tries")


def sample_poses(task: Task, rng: np.random.Generator) -> tuple[dict[str, Pose], dict[str, float]]:
    """Poses for every movable (unused ones parked out of reach) and fixture joint values for `task`."""
    for _ in range(MAX_TRIES):
        try:
            return _sample_once(task, rng)
        except PlacementError:
            continue
    raise PlacementError(f"could not place the objects of task {task.name!r}; its regions are too crowded")


def _sample_once(task: Task, rng: np.random.Generator) -> tuple[dict[str, Pose], dict[str, float]]:
    init = task.init
    joints = dict(task.joints)
    poses: dict[str, Pose] = {}
    taken: list[tuple[float, float, float]] = []
    shelf_slots = list(rng.permutation(len(layout.SHELF_SLOTS)))
    drawer_slots = list(rng.permutation(len(layout.DRAWER_SLOTS)))
    # Vessels first: they are the largest.
    for name in sorted(init, key=lambda n: n not in layout.VESSELS):
        where = init[name]
        radius = layout.spacing_radius(name)
        if where == ("stove",):
            x, y = np.array(layout.FIXTURES["stove"]) + rng.uniform(-0.01, 0.01, 2)
            poses[name] = (x, y, layout.STOVE_TOP_Z + 0.002, rng.uniform(-0.05, 0.05))
            continue
        if where == ("shelf",):
            x, y = np.array(layout.SHELF_SLOTS[shelf_slots.pop()]) + rng.uniform(-0.004, 0.004, 2)
            poses[name] = (x, y, layout.item_rest_z(name, layout.SHELF_TOP_Z) + 0.002, rng.uniform(-0.1, 0.1))
            continue
        if where == ("drawer",):
            tray_x, tray_y = layout.drawer_tray_xy(joints["drawer_slide"])
            x = tray_x + layout.DRAWER_SLOTS[drawer_slots.pop()] + rng.uniform(-0.004, 0.004)
            y = tray_y + rng.uniform(-0.01, 0.01)
            poses[name] = (x, y, layout.item_rest_z(name, layout.DRAWER_FLOOR_Z) + 0.002, rng.uniform(-0.1, 0.1))
            continue
        x, y = free_spot(rng, where, radius, taken)
        taken.append((x, y, radius))
        yaw = rng.uniform(-0.05, 0.05) if name in layout.VESSELS else rng.uniform(-ITEM_YAW, ITEM_YAW)
        z = layout.TABLE_Z + 0.002 if name in layout.VESSELS else layout.item_rest_z(name) + 0.002
        poses[name] = (x, y, z, yaw)
    parking = iter(layout.PARKING)
    for name in layout.MOVABLES:
        if name not in poses:
            x, y = next(parking)
            z = layout.TABLE_Z + 0.002 if name in layout.VESSELS else layout.item_rest_z(name) + 0.002
            poses[name] = (x, y, z, 0.0)
    return poses, joints
