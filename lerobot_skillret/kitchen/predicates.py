"""Predicates over simulator state: the only definition of "bread is on the plate", "drawer is closed", ...

Each predicate reads a scene through three accessors (`body_pos`, `body_quat`, `joint`), so this module imports
no simulator and tasks, primitives (success checks) and the gym env all share it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lerobot_skillret.kitchen import layout


class SceneState(Protocol):
    def body_pos(self, name: str) -> np.ndarray: ...
    def body_quat(self, name: str) -> np.ndarray: ...
    def joint(self, name: str) -> float: ...


@dataclass(frozen=True)
class Predicate:
    """A named boolean test of the scene (name is used in logs and docs)."""

    name: str
    test: Callable[[SceneState], bool]

    def __call__(self, scene: SceneState) -> bool:
        return bool(self.test(scene))


SWITCH_JOINTS = {"light": "light_switch_joint", "burner": "burner_switch_joint"}
DRAWER_OPEN_BELOW = -0.15  # slide joint below this = open (0 = closed, -0.2 = fully open)
DRAWER_CLOSED_ABOVE = -0.015


def yaw(quat_wxyz: np.ndarray) -> float:
    """Heading (rad) of a (w, x, y, z) quaternion: the first angle of its intrinsic ZYX Euler angles.

    The closed form, not scipy's `Rotation.as_euler("ZYX")` (equal to ~1e-14): this module stays import-light (the
    tasks and the EnvConfig import it at plugin registration) and predicates run every env step.
    """
    w, x, y, z = quat_wxyz
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _upright(scene: SceneState, obj: str) -> bool:
    _, x, y, _ = scene.body_quat(obj)
    return 1 - 2 * (x * x + y * y) > 0.9  # body z-axis within ~25 deg of world z


def _local_xy(scene: SceneState, obj: str, frame: str) -> np.ndarray:
    d = scene.body_pos(obj)[:2] - scene.body_pos(frame)[:2]
    heading = yaw(scene.body_quat(frame))
    c, s = np.cos(heading), np.sin(heading)
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def _resting(scene: SceneState, obj: str, surface_z: float, tol: float = 0.02) -> bool:
    return abs(scene.body_pos(obj)[2] - layout.item_rest_z(obj, surface_z)) < tol


def switch_on(switch: str, on: bool = True) -> Predicate:
    joint = SWITCH_JOINTS[switch]
    return Predicate(f"{switch}_{'on' if on else 'off'}", lambda s: (s.joint(joint) > 0) == on)


def drawer_open() -> Predicate:
    return Predicate("drawer_open", lambda s: s.joint("drawer_slide") < DRAWER_OPEN_BELOW)


def drawer_closed() -> Predicate:
    return Predicate("drawer_closed", lambda s: s.joint("drawer_slide") > DRAWER_CLOSED_ABOVE)


def on_plate(obj: str) -> Predicate:
    def test(s: SceneState) -> bool:
        cx, cy = layout.FIXTURES["serving"]
        p = s.body_pos(obj)
        return np.hypot(p[0] - cx, p[1] - cy) < layout.PLATE_RADIUS and _resting(s, obj, layout.TABLE_Z + 0.01)

    return Predicate(f"{obj}_on_plate", test)


def on_placemat_side(obj: str, side: str) -> Predicate:
    """`side` is "left" (+y of the plate, the robot's left) or "right"."""
    sign = 1.0 if side == "left" else -1.0

    def test(s: SceneState) -> bool:
        cx, cy = layout.FIXTURES["serving"]
        hx, hy = layout.PLACEMAT_HALF
        p = s.body_pos(obj)
        on_mat = abs(p[0] - cx) < hx and abs(p[1] - cy) < hy
        beside = sign * (p[1] - cy) > layout.PLATE_RADIUS + 0.01
        return on_mat and beside and _resting(s, obj, layout.TABLE_Z + 0.004) and _upright(s, obj)

    return Predicate(f"{obj}_{side}_of_plate", test)


def in_vessel(obj: str, vessel: str) -> Predicate:
    def test(s: SceneState) -> bool:
        hx, hy = layout.VESSELS[vessel]["inner_half"]
        lx, ly = _local_xy(s, obj, vessel)
        dz = s.body_pos(obj)[2] - s.body_pos(vessel)[2]
        return abs(lx) < hx and abs(ly) < hy and 0.0 < dz < 0.08

    return Predicate(f"{obj}_in_{vessel}", test)


def vessel_on_stove(vessel: str) -> Predicate:
    def test(s: SceneState) -> bool:
        sx, sy = layout.FIXTURES["stove"]
        hx, hy = layout.STOVE_HALF
        p = s.body_pos(vessel)
        return abs(p[0] - sx) < hx - 0.03 and abs(p[1] - sy) < hy - 0.03 and abs(p[2] - layout.STOVE_TOP_Z) < 0.015

    return Predicate(f"{vessel}_on_stove", test)


def in_drawer(obj: str) -> Predicate:
    def test(s: SceneState) -> bool:
        tray = s.body_pos("drawer_tray")
        hx, hy = layout.DRAWER_TRAY_INNER_HALF
        p = s.body_pos(obj)
        return abs(p[0] - tray[0]) < hx and abs(p[1] - tray[1]) < hy and p[2] < layout.DRAWER_FLOOR_Z + 0.05

    return Predicate(f"{obj}_in_drawer", test)


def on_table(obj: str) -> Predicate:
    """Resting directly on the reachable table top (not on the shelf, in the drawer or in a vessel)."""

    def test(s: SceneState) -> bool:
        x0, x1, y0, y1 = layout.WORK_AREA
        p = s.body_pos(obj)
        return x0 < p[0] < x1 and y0 < p[1] < y1 and _resting(s, obj, layout.TABLE_Z, tol=0.006)

    return Predicate(f"{obj}_on_table", test)


def on_shelf(obj: str) -> Predicate:
    def test(s: SceneState) -> bool:
        sx, sy = layout.FIXTURES["shelf"]
        p = s.body_pos(obj)
        return abs(p[0] - sx) < 0.06 and abs(p[1] - sy) < 0.05 and _resting(s, obj, layout.SHELF_TOP_Z)

    return Predicate(f"{obj}_on_shelf", test)
