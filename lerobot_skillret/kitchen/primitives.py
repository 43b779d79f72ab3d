"""Scripted primitives on the kitchen scene: pick-and-place, drawer, switches, vessels.

A `Driver` turns waypoints into OSC_POSE actions (a clipped proportional controller on the remaining error; each
OSC step's goal is the current pose plus the delta, so this is a simple position servo) and passes every action
through one hook, so generators can record (observation, action, primitive) per frame. Each primitive judges
success by the scene state (never by having reached a waypoint) and retries a failed attempt.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen import predicates as P
from lerobot_skillret.kitchen.sampling import free_spot

# Primitive names; a frame's `primitive_index` indexes this tuple (stored with every dataset).
PRIMITIVES = ("pick_place", "open_drawer", "close_drawer", "toggle", "move_vessel")
PLACE_REGIONS = ("plate", "placemat_left", "placemat_right", "pan", "pot", "drawer", "table", "shelf")

SAFE_Z = layout.TABLE_Z + 0.2
POS_SCALE = 0.05  # metres per unit of OSC position action
ROT_SCALE = 0.5  # radians per unit of OSC rotation action
# Gripper pointing straight down, fingers closing along world y (columns: eef axes in the world frame).
DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
OPEN, CLOSED = -1.0, 1.0
RETRIES = 2


class OutOfSteps(Exception):
    """The driver's step budget is spent (episode length reached)."""


class Driver:
    """Executes waypoints on a scene, adding action noise and waypoint jitter, under a step budget."""

    def __init__(
        self,
        scene,
        rng: np.random.Generator,
        action_noise: float = 0.0,
        jitter: float = 0.0,
        budget: int = 10**9,
        on_step: Callable[[np.ndarray, int], None] | None = None,
    ):
        self.scene, self.rng = scene, rng
        self.action_noise, self.jitter = action_noise, jitter
        self.budget, self.steps = budget, 0
        self.on_step = on_step
        self.label = 0
        self.grip = OPEN

    def act(self, action: np.ndarray) -> None:
        if self.steps >= self.budget:
            raise OutOfSteps
        action = np.asarray(action, dtype=np.float64).copy()
        if self.action_noise:
            action[:6] += self.rng.normal(0.0, self.action_noise, 6)
        # float32 like the stored dataset actions, so a replay applies exactly the recorded numbers
        action = np.clip(action, -1.0, 1.0).astype(np.float32)
        if self.on_step is not None:
            self.on_step(action, self.label)  # observation is taken before the step
        self.scene.step(action.astype(np.float64))
        self.steps += 1

    def servo_action(self, target: np.ndarray, speed: float = 1.0) -> np.ndarray:
        err = target - self.scene.eef_pos()
        rot = Rotation.from_matrix(DOWN @ self.scene.eef_mat().T).as_rotvec()  # orientation error, axis-angle
        return np.concatenate([np.clip(err / POS_SCALE, -speed, speed), np.clip(rot / ROT_SCALE, -1, 1), [self.grip]])

    def move(self, target, tol: float = 0.008, max_steps: int = 60, jitter: bool = True, speed: float = 1.0) -> bool:
        target = np.asarray(target, dtype=np.float64)
        if jitter and self.jitter:
            target = target + self.rng.normal(0.0, self.jitter, 3)
        for _ in range(max_steps):
            if np.linalg.norm(target - self.scene.eef_pos()) < tol:
                return True
            self.act(self.servo_action(target, speed))
        return False

    def hold(self, steps: int, grip: float | None = None) -> None:
        """Stay in place (e.g. while the gripper opens or closes)."""
        if grip is not None:
            self.grip = grip
        target = self.scene.eef_pos()
        for _ in range(steps):
            self.act(self.servo_action(target))

    def lift(self, z: float = SAFE_Z) -> None:
        p = self.scene.eef_pos()
        self.move([p[0], p[1], z], tol=0.02, jitter=False)


# ----- geometry helpers -----
def _handle_world(scene, vessel: str) -> np.ndarray:
    pos, yaw = scene.body_pos(vessel), P.yaw(scene.body_quat(vessel))
    hx, hy, hz = layout.VESSELS[vessel]["handle"]
    c, s = np.cos(yaw), np.sin(yaw)
    return pos + np.array([c * hx - s * hy, s * hx + c * hy, hz])


def _grasp_point(scene, obj: str) -> np.ndarray:
    p = scene.body_pos(obj)
    # Fingertips reach ~1 cm below the eef site: keep them off the surface the item rests on.
    half_z = layout.ITEMS[obj].half[2]
    return np.array([p[0], p[1], max(p[2] + 0.3 * half_z, p[2] - half_z + 0.017)])


def place_target(scene, obj: str, region: str, rng: np.random.Generator) -> np.ndarray:
    """Resting position of `obj`'s centre when placed in `region` (a free slot / spot where there are several)."""
    others = [n for n in layout.MOVABLES if n not in (obj, region)]
    if region == "plate":
        x, y = layout.FIXTURES["serving"]
        return np.array([x, y, layout.item_rest_z(obj, layout.TABLE_Z + 0.01)])
    if region in ("placemat_left", "placemat_right"):
        x, y = layout.FIXTURES["serving"]
        dy = 0.09 if region == "placemat_left" else -0.09
        return np.array([x, y + dy, layout.item_rest_z(obj, layout.TABLE_Z + 0.004)])
    if region in ("pan", "pot", "drawer"):
        if region == "drawer":
            centre = np.array([*layout.drawer_tray_xy(scene.joint("drawer_slide")), layout.DRAWER_FLOOR_Z])
            slots, yaw = layout.DRAWER_SLOTS, 0.0
        else:
            centre = scene.body_pos(region) + np.array([0, 0, layout.VESSELS[region]["floor"][0]])
            slots, yaw = layout.VESSELS[region]["slots"], P.yaw(scene.body_quat(region))
        points = [centre + np.array([np.cos(yaw) * dx, np.sin(yaw) * dx, 0.0]) for dx in slots]
        # The free slot farthest from every other object.
        best = max(points, key=lambda q: min(np.linalg.norm(scene.body_pos(n)[:2] - q[:2]) for n in others))
        return np.array([best[0], best[1], layout.item_rest_z(obj, best[2])])
    if region == "shelf":
        slot = max(
            layout.SHELF_SLOTS,
            key=lambda q: min(np.linalg.norm(scene.body_pos(n)[:2] - np.array(q)) for n in others),
        )
        return np.array([slot[0], slot[1], layout.item_rest_z(obj, layout.SHELF_TOP_Z)])
    if region == "table":
        taken = [(*scene.body_pos(n)[:2], layout.spacing_radius(n)) for n in others]
        x, y = free_spot(rng, layout.TABLE_DROP_REGIONS, layout.spacing_radius(obj), taken)
        return np.array([x, y, layout.item_rest_z(obj)])
    raise ValueError(f"unknown place region {region!r}; choose one of {PLACE_REGIONS}")


def place_check(obj: str, region: str) -> P.Predicate:
    """The predicate that says `obj` was placed in `region`."""
    if region == "plate":
        return P.on_plate(obj)
    if region in ("placemat_left", "placemat_right"):
        return P.on_placemat_side(obj, region.split("_")[1])
    if region in ("pan", "pot"):
        return P.in_vessel(obj, region)
    return {"drawer": P.in_drawer, "table": P.on_table, "shelf": P.on_shelf}[region](obj)


# ----- primitives -----
def _pick(d: Driver, obj: str) -> bool:
    scene = d.scene
    start_z = scene.body_pos(obj)[2]
    g = _grasp_point(scene, obj)
    d.grip = OPEN
    d.move([g[0], g[1], SAFE_Z], tol=0.015)
    g = _grasp_point(scene, obj)
    d.move([g[0], g[1], g[2] + 0.06], tol=0.01)
    d.move(g, tol=0.006, max_steps=40, jitter=False)
    d.hold(10, grip=CLOSED)
    d.lift()
    held = np.linalg.norm(scene.body_pos(obj) - scene.eef_pos()) < 0.06
    return held and scene.body_pos(obj)[2] > start_z + 0.04


def _release(d: Driver, eef_target: np.ndarray) -> None:
    d.move([eef_target[0], eef_target[1], SAFE_Z], tol=0.015)
    d.move(eef_target + np.array([0, 0, 0.04]), tol=0.01, jitter=False)
    d.move(eef_target, tol=0.006, max_steps=30, jitter=False)
    # Open the fingers only part way (the gripper command integrates): less to bump in pans and drawers.
    d.hold(6, grip=OPEN)
    d.hold(4, grip=0.0)
    d.lift()
    d.grip = OPEN


def pick_place(d: Driver, obj: str, region: str) -> bool:
    check = place_check(obj, region)
    for _ in range(1 + RETRIES):
        if _pick(d, obj):
            offset = d.scene.eef_pos() - d.scene.body_pos(obj)
            _release(d, place_target(d.scene, obj, region, d.rng) + offset + np.array([0, 0, 0.008]))
        else:
            d.hold(6, grip=OPEN)
            d.lift()
        if check(d.scene):
            return True
    return False


def _drawer_to(d: Driver, target_qpos: float, done: P.Predicate) -> bool:
    scene = d.scene
    for _ in range(1 + RETRIES):
        q = scene.joint("drawer_slide")
        hx, hy, hz = layout.DRAWER_HANDLE_OFFSET
        tray_x, tray_y = layout.drawer_tray_xy(q)
        handle = np.array([tray_x + hx - 0.005, tray_y + hy, layout.TABLE_Z + layout.DRAWER_LIFT + hz])
        d.grip = OPEN
        d.move([handle[0], handle[1], SAFE_Z - 0.05], tol=0.015)
        d.move(handle + np.array([0, 0, 0.05]), tol=0.01)
        d.move(handle, tol=0.006, max_steps=30, jitter=False)
        d.hold(10, grip=CLOSED)
        overshoot = 0.02 * np.sign(target_qpos - q)
        d.move(handle + np.array([target_qpos - q + overshoot, 0, 0]), tol=0.01, max_steps=70, jitter=False, speed=0.6)
        d.hold(8, grip=OPEN)
        d.lift(SAFE_Z - 0.05)
        if done(scene):
            return True
    return False


def open_drawer(d: Driver) -> bool:
    return _drawer_to(d, layout.DRAWER_RANGE[1], P.drawer_open())


def close_drawer(d: Driver) -> bool:
    return _drawer_to(d, layout.DRAWER_RANGE[0], P.drawer_closed())


def toggle(d: Driver, switch: str, state: str) -> bool:
    """Slide a switch's knob to "on" (+x) or "off" (-x) with closed fingers."""
    on = state == "on"
    done = P.switch_on(switch, on=on)
    scene = d.scene
    bx, by = layout.FIXTURES[switch]
    z = layout.TABLE_Z + 0.037
    sign = 1.0 if on else -1.0
    for _ in range(1 + RETRIES):
        knob_x = bx + scene.joint(P.SWITCH_JOINTS[switch])
        start = np.array([knob_x - sign * 0.045, by, z])
        d.lift()  # never close the fingers near whatever the last primitive touched
        d.grip = CLOSED
        d.move([start[0], start[1], SAFE_Z], tol=0.015)
        d.move(start, tol=0.008, max_steps=40, jitter=False)
        d.move([bx + sign * (layout.SWITCH_RANGE[1] - 0.022 + 0.025), by, z], tol=0.008, max_steps=40, jitter=False)
        d.move(d.scene.eef_pos() - np.array([sign * 0.02, 0, 0]), tol=0.008, max_steps=15, jitter=False)
        d.lift(z + 0.1)
        if done(scene):
            return True
    return False


def move_vessel(d: Driver, vessel: str, region: str) -> bool:
    """Carry a pan/pot by its handle to the stove (region "stove") or to its table spot."""
    if region == "stove":
        target = np.array([*layout.FIXTURES["stove"], layout.STOVE_TOP_Z])
        done = P.vessel_on_stove(vessel)
    else:
        x0, x1, y0, y1 = layout.REGIONS[region]
        target = np.array([(x0 + x1) / 2, (y0 + y1) / 2, layout.TABLE_Z])
        done = P.Predicate(
            f"{vessel}_at_{region}",
            lambda s: x0 - 0.03 < s.body_pos(vessel)[0] < x1 + 0.03 and y0 - 0.03 < s.body_pos(vessel)[1] < y1 + 0.03,
        )
    scene = d.scene
    for _ in range(1 + RETRIES):
        handle = _handle_world(scene, vessel)
        d.grip = OPEN
        d.move([handle[0], handle[1], SAFE_Z - 0.05], tol=0.015)
        d.move(handle + np.array([0, 0, 0.05]), tol=0.01)
        d.move(handle, tol=0.006, max_steps=30, jitter=False)
        d.hold(10, grip=CLOSED)
        offset = d.scene.eef_pos() - scene.body_pos(vessel)
        d.move(d.scene.eef_pos() + np.array([0, 0, 0.1]), tol=0.015, jitter=False)
        d.move(target + offset + np.array([0, 0, 0.1]), tol=0.012)
        d.move(target + offset + np.array([0, 0, 0.01]), tol=0.006, max_steps=40, jitter=False)
        d.hold(8, grip=OPEN)
        d.lift(SAFE_Z - 0.05)
        if done(scene):
            return True
    return False


PRIMITIVE_FUNCS: dict[str, Callable[..., bool]] = {
    "pick_place": pick_place,
    "open_drawer": open_drawer,
    "close_drawer": close_drawer,
    "toggle": toggle,
    "move_vessel": move_vessel,
}
assert tuple(PRIMITIVE_FUNCS) == PRIMITIVES


def run_primitive(d: Driver, name: str, *args: str) -> bool:
    d.label = PRIMITIVES.index(name)
    return PRIMITIVE_FUNCS[name](d, *args)
