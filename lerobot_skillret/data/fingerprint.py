"""Content fingerprints of local LeRobotDatasets and checkpoints.

One definition shared by the window cache (invalidated when the dataset changes) and the retrieval file
(refused when it was computed on another dataset or checkpoint).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

_DATASET_PARTS = ("meta", "data")  # videos are derived from the same frames and are skipped for speed


def _hash_files(files: list[Path], base: Path) -> str:
    digest = hashlib.sha1()
    for path in sorted(files):
        digest.update(str(path.relative_to(base)).encode())
        with path.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()[:16]


def dataset_fingerprint(root: str | Path) -> str:
    """Hash of a LeRobotDataset folder's metadata and frame tables (not its videos)."""
    root = Path(root)
    files = [p for part in _DATASET_PARTS for p in (root / part).rglob("*") if p.is_file()]
    if not files:
        raise FileNotFoundError(f"{root} holds no LeRobotDataset (no files under meta/ or data/).")
    return _hash_files(files, root)


def checkpoint_fingerprint(pretrained_dir: str | Path) -> str:
    """Hash of a saved policy's weights and config (a `pretrained_model/` folder)."""
    root = Path(pretrained_dir)
    files = [root / name for name in ("config.json", "model.safetensors") if (root / name).is_file()]
    if len(files) < 2:
        raise FileNotFoundError(
            f"{root} is not a skillret checkpoint: it needs config.json and model.safetensors "
            "(pass the `pretrained_model` folder of a lerobot-train checkpoint)."
        )
    return _hash_files(files, root)
