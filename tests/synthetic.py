"""Tiny synthetic LeRobotDatasets (format v3.0) written locally, for tests of every area.

Built with LeRobot's own writer (`create` / `add_frame` / `save_episode` / `finalize`) so tests exercise the real
on-disk format and loader; nothing touches the hub. Values are smooth random curves (sums of sinusoids), so windows
and nearest neighbours are meaningful, and every array is a function of `seed` alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

IMAGE_KEY = "observation.images.agentview"
IMAGE_SIZE = 8  # pixels per side: enough to be a real image feature, small enough to keep tests fast
NUM_PRIMITIVES = 4


def synthetic_features(state_dim: int, env_dim: int, action_dim: int, with_images: bool) -> dict[str, dict]:
    """LeRobot feature spec of the synthetic datasets (one source of truth for tests that need the names)."""
    features: dict[str, dict] = {
        "observation.state": {"dtype": "float32", "shape": (state_dim,), "names": None},
        "observation.environment_state": {"dtype": "float32", "shape": (env_dim,), "names": None},
        "action": {"dtype": "float32", "shape": (action_dim,), "names": None},
        "primitive_index": {"dtype": "int64", "shape": (1,), "names": None},
    }
    if with_images:
        features[IMAGE_KEY] = {
            "dtype": "image",
            "shape": (IMAGE_SIZE, IMAGE_SIZE, 3),
            "names": ["height", "width", "channels"],
        }
    return features


def _smooth_curves(rng: np.random.Generator, length: int, dim: int) -> np.ndarray:
    """(length, dim) sums of three sinusoids with random frequency, phase and amplitude per dimension."""
    t = np.arange(length, dtype=np.float64)[:, None, None]
    freq = rng.uniform(0.02, 0.3, size=(1, dim, 3))
    phase = rng.uniform(0.0, 2 * np.pi, size=(1, dim, 3))
    amp = rng.uniform(0.2, 1.0, size=(1, dim, 3))
    offset = rng.normal(0.0, 0.5, size=(1, dim))
    return (amp * np.sin(freq * t + phase)).sum(-1) + offset


def _primitive_segments(rng: np.random.Generator, length: int) -> np.ndarray:
    """Piecewise-constant primitive labels: segments of 5-15 frames, like a scripted demo's sub-skills."""
    labels = np.empty(length, dtype=np.int64)
    start = 0
    while start < length:
        stop = min(length, start + int(rng.integers(5, 16)))
        labels[start:stop] = rng.integers(0, NUM_PRIMITIVES)
        start = stop
    return labels


def make_synthetic_dataset(
    root: str | Path,
    repo_id: str = "test/synthetic",
    num_episodes: int = 4,
    min_len: int = 15,
    max_len: int = 40,
    state_dim: int = 6,
    env_dim: int = 5,
    action_dim: int = 7,
    seed: int = 0,
    with_images: bool = False,
    fps: int = 20,
) -> Path:
    """Write a synthetic dataset into the new folder `root` (must not exist) and return `root`.

    Episode lengths are uniform in [min_len, max_len]; actions lie in [-1, 1]; `primitive_index` is an int64 label
    per frame; with `with_images` an 8x8 RGB `observation.images.agentview` (stored as `image`, not video, for speed).
    """
    root = Path(root)
    if num_episodes < 1 or min_len < 1 or max_len < min_len:
        raise ValueError(
            f"need num_episodes >= 1 and 1 <= min_len <= max_len, got {num_episodes=}, {min_len=}, {max_len=}"
        )
    rng = np.random.default_rng(seed)
    features = synthetic_features(state_dim, env_dim, action_dim, with_images)
    dataset = LeRobotDataset.create(repo_id, fps, features, root=root, use_videos=False)
    for episode in range(num_episodes):
        length = int(rng.integers(min_len, max_len + 1))
        state = _smooth_curves(rng, length, state_dim).astype(np.float32)
        env_state = _smooth_curves(rng, length, env_dim).astype(np.float32)
        action = np.tanh(_smooth_curves(rng, length, action_dim)).astype(np.float32)
        primitive = _primitive_segments(rng, length)
        images = rng.integers(0, 256, size=(length, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
        for i in range(length):
            frame = {
                "observation.state": state[i],
                "observation.environment_state": env_state[i],
                "action": action[i],
                "primitive_index": primitive[i : i + 1],
                "task": f"synthetic task {episode % 2}",
            }
            if with_images:
                frame[IMAGE_KEY] = images[i]
            dataset.add_frame(frame)
        dataset.save_episode()
    dataset.finalize()
    return root
