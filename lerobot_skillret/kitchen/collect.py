"""What a generated dataset contains: the episodes simulated (their seeds), and one episode's arrays.

Workers only simulate; the parent process writes the dataset (one writer, ordered by episode seed). This module is
part of the kitchen fingerprint, so everything that decides a dataset's content lives here, not in the CLI.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.expert import reset_scene, run_expert
from lerobot_skillret.kitchen.play import play_scene_task, run_play
from lerobot_skillret.kitchen.primitives import Driver
from lerobot_skillret.kitchen.tasks import get_task

PLAY_ACTION_NOISE = 0.05
PLAY_JITTER = 0.005
DEMO_ACTION_NOISE = 0.0
DEMO_JITTER = 0.003
PLAY_TASK_TEXT = "play"  # the LeRobot task string of every play frame (demos carry their task's description)
MAX_ATTEMPTS_FACTOR = 3  # demos: give up after this many attempts per requested episode


@dataclass
class EpisodeJob:
    kind: str  # "play" or "demos"
    seed: int
    task: str | None = None  # demos only
    steps: int = 0  # play only: frames per episode
    cameras: tuple[str, ...] = ()  # rendered at observations.DEFAULT_IMAGE_SIZE


@dataclass
class Episode:
    seed: int
    task: str  # the task whose scene/demo this is ("play" episodes: the scene's source task)
    success: bool
    initial_state: np.ndarray
    frames: dict[str, list] = field(default_factory=dict)  # dataset key -> per-frame values
    log: list = field(default_factory=list)


def episode_jobs(
    kind: str, seed: int, episodes: int, task: str | None = None, steps: int = 0, cameras: tuple[str, ...] = ()
) -> list[EpisodeJob]:
    """The episodes to simulate, in order; episode i's seed depends only on `seed` and i, so the dataset does not
    depend on the number of workers. Demos get MAX_ATTEMPTS_FACTOR attempts per episode (failures are dropped)."""
    attempts = episodes if kind == "play" else episodes * MAX_ATTEMPTS_FACTOR
    return [EpisodeJob(kind, seed * 1_000_003 + i, task=task, steps=steps, cameras=cameras) for i in range(attempts)]


_WORKER: dict = {}


def _scene(cameras: tuple[str, ...]):
    if _WORKER.get("cameras") != cameras:
        from lerobot_skillret.kitchen.rendering import CameraRenderer
        from lerobot_skillret.kitchen.scene import KitchenScene

        scene = _WORKER.get("scene") or KitchenScene()
        camera = CameraRenderer(scene, O.DEFAULT_IMAGE_SIZE) if cameras else None
        _WORKER.update(cameras=cameras, scene=scene, cam=camera)
    return _WORKER["scene"], _WORKER["cam"]


def run_episode(job: EpisodeJob) -> Episode:
    scene, cam = _scene(job.cameras)
    rng = np.random.default_rng(job.seed)
    task = get_task(job.task) if job.kind == "demos" else play_scene_task(rng)
    reset_scene(scene, task, rng)
    episode = Episode(seed=job.seed, task=task.name, success=False, initial_state=scene.get_sim_state())
    frames: dict[str, list] = {}

    def record(action: np.ndarray, label: int) -> None:
        for key, value in O.to_dataset_frame(O.build_observation(scene, cam, job.cameras)).items():
            frames.setdefault(key, []).append(value)
        frames.setdefault("action", []).append(action.astype(np.float32))
        frames.setdefault(O.PRIMITIVE_KEY, []).append(np.array([label], dtype=np.int64))

    if job.kind == "demos":
        driver = Driver(scene, rng, DEMO_ACTION_NOISE, DEMO_JITTER, budget=task.max_steps, on_step=record)
        episode.success = run_expert(driver, task)
    elif job.kind == "play":
        driver = Driver(scene, rng, PLAY_ACTION_NOISE, PLAY_JITTER, budget=job.steps, on_step=record)
        episode.log = [(s.primitive, *s.args, ok) for s, ok in run_play(driver, rng)]
        episode.success = True
    else:
        raise ValueError(f"unknown episode kind {job.kind!r}; use 'play' or 'demos'")
    episode.frames = frames
    return episode
