"""An example task package: one more single-step task, built from the kitchen's predicates and primitives."""

from lerobot_skillret.kitchen import predicates as P
from lerobot_skillret.kitchen.tasks import Step, Task


def tasks() -> list[Task]:
    return [
        Task(
            name="milk_right_of_plate",
            description="Put the milk right of the plate.",
            goals=(P.on_placemat_side("milk", "right"),),
            init={"milk": ("front_left", "center")},  # where it starts (layout regions); other objects are parked
            max_steps=250,  # rollout limit: about twice the scripted expert's steps
            plan=(Step("pick_place", ("milk", "placemat_right")),),  # the scripted expert's primitive calls
        )
    ]
