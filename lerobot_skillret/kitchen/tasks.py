"""Kitchen tasks as data: goal predicates, initial-state distribution, rollout length and a scripted plan.

One registry (`TASKS`) is used by the gym env, the generators, the experts and the EnvConfig. Adding a task is one
`Task(...)` entry. Import-light: no simulator here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen import predicates as P

DEFAULT_JOINTS = {"drawer_slide": 0.0, "light_switch_joint": -0.025, "burner_switch_joint": -0.025}


@dataclass(frozen=True)
class Step:
    """One scripted primitive call: `primitive` name from `primitives.PRIMITIVES` plus its arguments."""

    primitive: str
    args: tuple[str, ...] = ()


@dataclass(frozen=True)
class Task:
    name: str
    description: str
    goals: tuple[P.Predicate, ...]
    # object -> where it starts: a region of layout.REGIONS, or "stove" / "shelf" / "drawer"; the others are parked
    init: dict[str, tuple[str, ...]]
    max_steps: int
    plan: tuple[Step, ...]
    joints: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_JOINTS))
    # objects that may be swapped among themselves at init (e.g. which block colour starts in the drawer)
    shuffle: tuple[str, ...] = ()

    def success(self, scene: P.SceneState) -> bool:
        return all(goal(scene) for goal in self.goals)

    def goals_met(self, scene: P.SceneState) -> tuple[bool, ...]:
        return tuple(bool(goal(scene)) for goal in self.goals)

    def progress(self, scene: P.SceneState, met_at_reset: tuple[bool, ...]) -> float:
        """Fraction of the goals unmet at reset that are met now: the env's reward, so lerobot-eval's
        `avg_max_reward` is subtask progress. Goals that hold from the start (cook's pan on the stove) earn nothing."""
        todo = [goal for goal, met in zip(self.goals, met_at_reset, strict=True) if not met]
        return sum(bool(goal(scene)) for goal in todo) / len(todo) if todo else 1.0

    def unmet(self, scene: P.SceneState) -> list[str]:
        return [goal.name for goal in self.goals if not goal(scene)]


TABLE = ("front_left", "center")
B1, B2, B3 = layout.BLOCKS

TASKS: dict[str, Task] = {
    t.name: t
    for t in (
        Task(
            name="breakfast",
            description="Serve breakfast: bread on the plate, butter left of the plate and milk right of it.",
            goals=(P.on_plate("bread"), P.on_placemat_side("butter", "left"), P.on_placemat_side("milk", "right")),
            init={"bread": TABLE, "butter": TABLE, "milk": TABLE},
            max_steps=600,
            plan=(
                Step("pick_place", ("bread", "plate")),
                Step("pick_place", ("butter", "placemat_left")),
                Step("pick_place", ("milk", "placemat_right")),
            ),
        ),
        Task(
            name="cook",
            description="Cook: put the fish, the sausage and the tomato into the pan on the stove and turn the burner on.",
            goals=(
                P.in_vessel("fish", "pan"),
                P.in_vessel("sausage", "pan"),
                P.in_vessel("tomato", "pan"),
                P.vessel_on_stove("pan"),
                P.switch_on("burner"),
            ),
            init={"pan": ("stove",), "fish": TABLE, "sausage": TABLE, "tomato": TABLE},
            max_steps=800,
            plan=(
                Step("pick_place", ("fish", "pan")),
                Step("pick_place", ("sausage", "pan")),
                Step("pick_place", ("tomato", "pan")),
                Step("toggle", ("burner", "on")),
            ),
        ),
        Task(
            name="setup_pan",
            description="Set up the pan: move the pan from the table onto the stove, then put the fish and the sausage in.",
            goals=(P.vessel_on_stove("pan"), P.in_vessel("fish", "pan"), P.in_vessel("sausage", "pan")),
            init={"pan": ("pan_table",), "fish": ("center",), "sausage": ("center",)},
            max_steps=700,
            plan=(
                Step("move_vessel", ("pan", "stove")),
                Step("pick_place", ("fish", "pan")),
                Step("pick_place", ("sausage", "pan")),
            ),
        ),
        Task(
            name="setting_up",
            description="Setting up: switch the light on, take the block out of the drawer and move the shelf blocks "
            "onto the table.",
            goals=(P.switch_on("light"), *(P.on_table(b) for b in layout.BLOCKS)),
            init={B1: ("drawer",), B2: ("shelf",), B3: ("shelf",)},
            max_steps=900,
            # The open drawer's handle overhangs the shelf: clear the shelf first, then open the drawer.
            plan=(
                Step("toggle", ("light", "on")),
                *(Step("pick_place", (b, "table")) for b in layout.BLOCKS if b != B1),
                Step("open_drawer"),
                Step("pick_place", (B1, "table")),
            ),
        ),
        Task(
            name="cleaning_up",
            description="Cleaning up: put all three blocks into the drawer, close it and switch the light off.",
            goals=(*(P.in_drawer(b) for b in layout.BLOCKS), P.drawer_closed(), P.switch_on("light", on=False)),
            init={B1: TABLE, B2: TABLE, B3: TABLE},
            joints={**DEFAULT_JOINTS, "light_switch_joint": 0.025},
            max_steps=1200,
            plan=(
                Step("open_drawer"),
                *(Step("pick_place", (b, "drawer")) for b in layout.BLOCKS),
                Step("close_drawer"),
                Step("toggle", ("light", "off")),
            ),
        ),
    )
}


def get_task(name: str) -> Task:
    if name not in TASKS:
        raise KeyError(f"Unknown kitchen task {name!r}; choose one of {sorted(TASKS)}.")
    return TASKS[name]
