"""Replay a recorded episode: restore its initial MuJoCo state and apply its recorded actions."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lerobot_skillret.kitchen.tasks import Task


def replay_actions(scene, initial_state: np.ndarray, actions: np.ndarray, task: Task) -> bool:
    """True if `task` is solved at any step of the replay (the gym env terminates there too)."""
    scene.reset()
    scene.set_sim_state(initial_state)
    for action in actions:
        scene.step(np.asarray(action, dtype=np.float64))
        if task.success(scene):
            return True
    return False


def episode_actions(root: str | Path) -> dict[int, np.ndarray]:
    """Recorded actions per episode index, read column-wise from a generated dataset's parquet files."""
    import pyarrow.parquet as pq

    table = pq.read_table(sorted(Path(root).glob("data/*/*.parquet")), columns=["episode_index", "action"])
    episodes = table.column("episode_index").to_numpy()
    actions = np.stack(table.column("action").to_numpy(zero_copy_only=False)).astype(np.float64)
    return {int(e): actions[episodes == e] for e in np.unique(episodes)}
