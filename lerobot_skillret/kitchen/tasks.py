"""Kitchen tasks as data: goal predicates, initial-state distribution, rollout length and a scripted plan.

One registry (`TASKS`) is used by the gym env, the generators, the experts, the EnvConfig and the pipeline.
The built-in tasks form a ladder: single-step tasks (one per sub-skill the long tasks use), two-step tasks, and the
seed's multi-step tasks (B.2/B.3). A task's level is the number of steps of its plan.

Tasks of your own need no edit here: an installed distribution that declares an entry point in the group
`lerobot_skillret.tasks` (its value: a `Task`, or a function returning an iterable of them) adds its tasks to
`TASKS` in every process, so `skillret-generate`, the gym ids, `lerobot-eval --env.task` and the pipeline all accept
them (see `examples/custom_task/`). Import-light: no simulator here.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib.metadata import entry_points

from lerobot_skillret.kitchen import layout
from lerobot_skillret.kitchen import predicates as P

# drawer closed, light and burner off
DEFAULT_JOINTS = {
    "drawer_slide": layout.DRAWER_RANGE[0],
    "light_switch_joint": layout.SWITCH_RANGE[0],
    "burner_switch_joint": layout.SWITCH_RANGE[0],
}
FIXTURE_PLACES = {"stove": 1, "shelf": len(layout.SHELF_SLOTS), "drawer": len(layout.DRAWER_SLOTS)}  # -> capacity


@dataclass(frozen=True)
class Step:
    """One scripted primitive call: `primitive` name from `primitives.PRIMITIVES` plus its arguments."""

    primitive: str
    args: tuple[str, ...] = ()


@dataclass(frozen=True)
class Task:
    name: str
    description: str
    goals: tuple[P.Predicate, ...]  # in the plan's order: `in_a_row` counts completed sub-goals in this order
    # object -> where it starts: a region of layout.REGIONS, or "stove" / "shelf" / "drawer"; the others are parked
    init: dict[str, tuple[str, ...]]
    max_steps: int
    plan: tuple[Step, ...]
    joints: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_JOINTS))
    # whether play episodes start from this task's scene (`play.play_scene_task`); False for a task added after the
    # published play data whose scene another built-in task already has, so that data stays as it was
    play_scene: bool = True

    def __post_init__(self) -> None:
        """A task of your own (an entry point) fails here, naming what is wrong, not deep inside the sampler."""

        def fail(why: str) -> None:
            raise ValueError(f"Kitchen task {self.name!r}: {why}.")

        if not self.goals or not self.plan or self.max_steps < 1:
            fail("needs goals, a plan and max_steps >= 1")
        unknown = sorted(set(self.init) - set(layout.MOVABLES))
        if unknown:
            fail(f"init names unknown objects {unknown}; choose from {list(layout.MOVABLES)}")
        for name, where in self.init.items():
            fixture = len(where) == 1 and where[0] in FIXTURE_PLACES
            if not where or not (fixture or set(where) <= set(layout.REGIONS)):
                fail(
                    f"init[{name!r}] = {where!r}: give one of {list(FIXTURE_PLACES)} alone, or table regions "
                    f"from {list(layout.REGIONS)}"
                )
        for place, capacity in FIXTURE_PLACES.items():
            count = sum(where == (place,) for where in self.init.values())
            if count > capacity:
                fail(f"{count} objects start on the {place}, which has room for {capacity}")
        if set(self.joints) != set(DEFAULT_JOINTS):
            fail(f"joints must set exactly {list(DEFAULT_JOINTS)}; got {list(self.joints)}")
        for joint, value in self.joints.items():
            low, high = sorted(layout.DRAWER_RANGE if joint == "drawer_slide" else layout.SWITCH_RANGE)
            if not low <= value <= high:
                fail(f"joints[{joint!r}] = {value} is outside its range [{low}, {high}]")

    def success(self, scene: P.SceneState) -> bool:
        return all(goal(scene) for goal in self.goals)

    def goals_met(self, scene: P.SceneState) -> tuple[bool, ...]:
        return tuple(bool(goal(scene)) for goal in self.goals)

    def progress(self, scene: P.SceneState, met_at_reset: tuple[bool, ...]) -> float:
        """Fraction of the goals unmet at reset that are met now: the env's reward, so lerobot-eval's
        `avg_max_reward` is subtask progress. Goals that hold from the start (cook's pan on the stove) earn nothing."""
        todo = [goal for goal, met in zip(self.goals, met_at_reset, strict=True) if not met]
        return sum(bool(goal(scene)) for goal in todo) / len(todo) if todo else 1.0

    def in_a_row(self, scene: P.SceneState, met_at_reset: tuple[bool, ...]) -> int:
        """Sub-goals completed in a row (CALVIN's chain length): the goals unmet at reset that hold now, counted in
        order up to the first that does not. Progress counts the fifth goal without the first; this does not."""
        count = 0
        for goal, met in zip(self.goals, met_at_reset, strict=True):
            if met:
                continue
            if not goal(scene):
                break
            count += 1
        return count

    def unmet(self, scene: P.SceneState) -> list[str]:
        return [goal.name for goal in self.goals if not goal(scene)]

    @property
    def level(self) -> int:
        """Rung of the task ladder: the number of sub-skills (primitive calls) the task chains."""
        return len(self.plan)


TABLE = ("front_left", "center")
B1, B2, B3 = layout.BLOCKS

LADDER: tuple[Task, ...] = (
    # --- level 1: one sub-skill each, the building blocks of the long tasks
    Task(
        name="bread_on_plate",
        description="Put the bread on the plate.",
        goals=(P.on_plate("bread"),),
        init={"bread": TABLE},
        max_steps=250,
        plan=(Step("pick_place", ("bread", "plate")),),
    ),
    Task(
        name="pan_on_stove",
        description="Move the pan by its handle from the table onto the stove.",
        goals=(P.vessel_on_stove("pan"),),
        init={"pan": ("pan_table",)},
        max_steps=300,
        plan=(Step("move_vessel", ("pan", "stove")),),
    ),
    Task(
        name="fish_in_pan",
        description="Put the fish into the pan on the stove.",
        goals=(P.in_vessel("fish", "pan"),),
        init={"pan": ("stove",), "fish": TABLE},
        max_steps=250,
        plan=(Step("pick_place", ("fish", "pan")),),
    ),
    Task(
        name="light_on",
        description="Switch the light on.",
        goals=(P.switch_on("light"),),
        init={},
        max_steps=200,
        plan=(Step("toggle", ("light", "on")),),
    ),
    Task(
        name="burner_on",
        description="Switch the burner on.",
        goals=(P.switch_on("burner"),),
        init={},
        max_steps=200,
        plan=(Step("toggle", ("burner", "on")),),
    ),
    Task(
        name="open_drawer",
        description="Open the drawer.",
        goals=(P.drawer_open(),),
        init={},
        max_steps=200,
        plan=(Step("open_drawer"),),
    ),
    # --- level 2: two sub-skills in a row
    Task(
        name="bread_and_butter",
        description="Put the bread on the plate and the butter left of the plate.",
        goals=(P.on_plate("bread"), P.on_placemat_side("butter", "left")),
        init={"bread": TABLE, "butter": TABLE},
        max_steps=450,
        plan=(Step("pick_place", ("bread", "plate")), Step("pick_place", ("butter", "placemat_left"))),
    ),
    Task(
        name="pan_and_fish",
        description="Move the pan onto the stove, then put the fish into it.",
        goals=(P.vessel_on_stove("pan"), P.in_vessel("fish", "pan")),
        init={"pan": ("pan_table",), "fish": ("center",)},
        max_steps=500,
        plan=(Step("move_vessel", ("pan", "stove")), Step("pick_place", ("fish", "pan"))),
    ),
    Task(
        name="fish_and_burner",
        description="Put the fish into the pan on the stove and turn the burner on.",
        goals=(P.in_vessel("fish", "pan"), P.switch_on("burner")),
        init={"pan": ("stove",), "fish": TABLE},
        max_steps=400,
        plan=(Step("pick_place", ("fish", "pan")), Step("toggle", ("burner", "on"))),
    ),
    # --- level 3: the 2-step bread_and_butter after a switch, made to land in the seed's target-only regime for
    # BC-RNN (15-50 %; measured rates: benchmarks/results/learnability/bc_rnn/results.md)
    Task(
        name="light_bread_butter",
        description="Switch the light on, then put the bread on the plate and the butter left of the plate.",
        goals=(P.switch_on("light"), P.on_plate("bread"), P.on_placemat_side("butter", "left")),
        init={"bread": TABLE, "butter": TABLE},
        max_steps=600,
        plan=(
            Step("toggle", ("light", "on")),
            Step("pick_place", ("bread", "plate")),
            Step("pick_place", ("butter", "placemat_left")),
        ),
        play_scene=False,  # bread_and_butter's scene
    ),
)

# The seed's multi-step tasks (B.2/B.3). Play episodes start from their scenes (see `play.play_scene_task`).
MULTI_STEP: tuple[Task, ...] = tuple(
    t
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
            goals=(P.switch_on("light"), *(P.on_table(b) for b in (B2, B3, B1))),
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
)


ENTRY_POINT_GROUP = "lerobot_skillret.tasks"


def _plugin_tasks() -> list[Task]:
    """Tasks declared by installed distributions in the entry-point group `lerobot_skillret.tasks`."""
    found: list[Task] = []
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        loaded = entry.load()
        tasks = loaded() if callable(loaded) and not isinstance(loaded, Task) else loaded
        tasks = [tasks] if isinstance(tasks, Task) else list(tasks)
        bad = [t for t in tasks if not isinstance(t, Task)]
        if bad:
            raise TypeError(
                f"Entry point {entry.name} = {entry.value} ({ENTRY_POINT_GROUP}) must give Task objects; got {bad!r}."
            )
        found += tasks
        logging.getLogger(__name__).debug("kitchen tasks from %s: %s", entry.value, [t.name for t in tasks])
    return found


def _registry(tasks: Iterable[Task]) -> dict[str, Task]:
    registry: dict[str, Task] = {}
    for task in tasks:
        if task.name in registry:
            raise ValueError(f"Two kitchen tasks are named {task.name!r}: rename one (task names are gym ids).")
        registry[task.name] = task
    return registry


BUILT_IN: tuple[Task, ...] = (*LADDER, *MULTI_STEP)  # the tasks this package defines (play starts from their scenes)
TASKS: dict[str, Task] = _registry([*BUILT_IN, *_plugin_tasks()])


def get_task(name: str) -> Task:
    if name not in TASKS:
        raise KeyError(f"Unknown kitchen task {name!r}; choose one of {sorted(TASKS)}.")
    return TASKS[name]
