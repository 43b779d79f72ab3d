"""Scripted experts: a task's plan executed as primitives, plus the seeded scene reset shared by all callers."""

from __future__ import annotations

import numpy as np

from lerobot_skillret.kitchen.primitives import Driver, OutOfSteps, run_primitive
from lerobot_skillret.kitchen.sampling import PlacementError, sample_poses
from lerobot_skillret.kitchen.tasks import Task


def reset_scene(scene, task: Task, rng: np.random.Generator) -> None:
    """Put `scene` into a fresh sample of `task`'s initial-state distribution."""
    poses, joints = sample_poses(task, rng)
    scene.reset_to(poses, joints, rng)


def run_expert(driver: Driver, task: Task) -> bool:
    """Run the task's plan; a step whose primitive fails (after its retries) ends the attempt. True on success."""
    try:
        for step in task.plan:
            if not run_primitive(driver, step.primitive, *step.args):
                return False
    except (OutOfSteps, PlacementError):  # out of time, or no free spot to put an item down
        return False
    return task.success(driver.scene)
