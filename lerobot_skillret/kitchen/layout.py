"""Where everything is on the kitchen table: the one place that knows fixture positions and object sizes.

Pure numbers, no simulator import, so task definitions, samplers and configs can use it cheaply. The MJCF assets
describe shapes in local frames; the scene puts each fixture at the position given here.
World frame: robot base at x ~ -0.56 facing +x, table top at z = TABLE_Z, +y is the robot's left.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Simulation settings shared by data generation and evaluation: 10 physics substeps per 20 Hz control step
# (robosuite's default 0.002 s gives 25 substeps and ~1.6x slower steps with the same scripted success).
SIMULATION_TIMESTEP = 0.005
CONTROL_FREQ = 20

TABLE_Z = 0.8
TABLE_FULL_SIZE = (0.8, 1.4, 0.05)

ROBOT_BASE_X = -0.5  # 6 cm closer than robosuite's table default: the arm's comfortable reach is ~0.66 m
# Fixture body positions (x, y) on the table top. Everything the arm touches lies within ~0.66 m (horizontal) of
# the robot base: beyond that the Panda straightens its elbow against a joint limit and OSC stalls.
FIXTURES: dict[str, tuple[float, float]] = {
    "stove": (0.07, 0.2),
    "burner": (0.0, 0.33),  # burner switch, left of the stove
    "light": (-0.25, -0.33),  # light switch, front right
    "lamp": (0.3, 0.0),
    "drawer": (0.22, -0.27),
    "serving": (-0.16, 0.0),
    "shelf": (-0.13, -0.2),  # closer to the base the arm misses; the drawer is opened after the shelf
}
STOVE_HALF = (0.1, 0.09)
STOVE_TOP_Z = TABLE_Z + 0.03
SHELF_TOP_Z = TABLE_Z + 0.03
PLATE_RADIUS = 0.045
PLACEMAT_HALF = (0.07, 0.13)

# Joint ranges of the state-carrying fixtures: (off/closed value, on/open value).
SWITCH_RANGE = (-0.025, 0.025)
DRAWER_RANGE = (0.0, -0.2)
DRAWER_TRAY_INNER_HALF = (0.074, 0.07)
DRAWER_LIFT = 0.08  # the cabinet stands on a plinth: a handle near the table top is beyond the arm's reach
DRAWER_FLOOR_Z = TABLE_Z + DRAWER_LIFT + 0.011
DRAWER_HANDLE_OFFSET = (-0.112, 0.0, 0.042)  # handle centre relative to the tray body
DRAWER_SLOTS = (-0.05, 0.0, 0.05)  # x offsets of block slots inside the tray

# Vessel geometry (local to the vessel body): handle offset, inner half-extents, floor height.
VESSELS: dict[str, dict[str, tuple[float, ...]]] = {
    "pan": {
        "handle": (-0.114, 0.0, 0.02),
        "inner_half": (0.075, 0.062),
        "floor": (0.008,),
        "slots": (-0.05, 0.0, 0.05),
    },
    "pot": {"handle": (-0.08, 0.0, 0.04), "inner_half": (0.046, 0.046), "floor": (0.008,), "slots": (0.0,)},
}


@dataclass(frozen=True)
class ItemSpec:
    """A graspable item: half-extents (x, y, z) and clearance radius used when spacing objects apart."""

    half: tuple[float, float, float]
    radius: float


# Heights set the grasp's tolerance: a learner that closes the fingers 1-2 cm high still grips a 5 cm item but only
# pinches the top of a 3 cm one. The bread was 3 cm tall; at 5 cm converged BC on bread_on_plate went from 44-58 % to
# 68-70 % (benchmarks/kitchen_learnability.py). The butter is 5 cm too (was 2.4 cm), which did not change
# bread_and_butter: BC lifts it in 1 of 20 rollouts either way and often moves the bread off the plate again (the
# chain, not the grasp, fails there). A 4 cm fish did not help fish_in_pan (46 % against 56-60 %), so it stayed 2.8 cm.
ITEMS: dict[str, ItemSpec] = {
    "bread": ItemSpec((0.035, 0.022, 0.025), 0.045),
    "butter": ItemSpec((0.022, 0.016, 0.025), 0.035),
    "milk": ItemSpec((0.02, 0.02, 0.035), 0.035),
    "fish": ItemSpec((0.024, 0.014, 0.014), 0.035),
    "sausage": ItemSpec((0.024, 0.012, 0.013), 0.035),
    "tomato": ItemSpec((0.018, 0.018, 0.015), 0.03),
    "block_red": ItemSpec((0.02, 0.02, 0.02), 0.035),
    "block_green": ItemSpec((0.02, 0.02, 0.02), 0.035),
    "block_blue": ItemSpec((0.02, 0.02, 0.02), 0.035),
}
BLOCKS = ("block_red", "block_green", "block_blue")
FOODS = ("bread", "butter", "milk", "fish", "sausage", "tomato")
# Footprint radius of a vessel (body centre to the far side of the handle) for spacing.
VESSEL_RADIUS = {"pan": 0.07, "pot": 0.06}
MOVABLES: tuple[str, ...] = (*ITEMS, *VESSELS)

# Rectangular table regions (x0, x1, y0, y1) for sampling positions of object centres.
REGIONS: dict[str, tuple[float, float, float, float]] = {
    "front_left": (-0.17, -0.08, 0.17, 0.30),  # x >= -0.17: closer is out of the arm's precise reach
    "center": (-0.05, 0.08, -0.07, 0.045),  # y <= 0.045: open fingers would touch the stove
    "pan_table": (-0.15, -0.13, 0.21, 0.25),  # pan on the table, clear of the stove, handle reachable
}
# Where items go when they are placed "on the table" (free spots are sampled in these regions).
TABLE_DROP_REGIONS = ("front_left", "center")
SHELF_SLOTS = ((-0.16, -0.2), (-0.1, -0.2))
# Objects not used by a scene wait out of reach along the table's sides.
PARKING = tuple((x, y) for y in (0.45, 0.58, -0.45, -0.58) for x in (-0.15, 0.0, 0.15))
# Table area that counts as "on the table" (reachable work surface).
WORK_AREA = (-0.3, 0.2, -0.36, 0.36)


def item_rest_z(name: str, surface_z: float = TABLE_Z) -> float:
    """Height of an item's centre when it rests on a surface."""
    return surface_z + ITEMS[name].half[2]


def spacing_radius(name: str) -> float:
    return ITEMS[name].radius if name in ITEMS else VESSEL_RADIUS[name]


def drawer_tray_xy(drawer_qpos: float) -> np.ndarray:
    """Tray centre in the world for a given slide joint position."""
    x, y = FIXTURES["drawer"]
    return np.array([x + drawer_qpos, y])
