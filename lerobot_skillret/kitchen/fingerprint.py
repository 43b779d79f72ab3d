"""A fingerprint of the simulated kitchen: a hash of the files that decide what generated data contains.

Why: the pipeline reuses finished datasets. One generated before the scene, the tasks or the scripted expert changed
(as when the bread became taller) would silently mix two kitchens into one comparison. Import-light: it reads files
and loads no simulator.
"""

from __future__ import annotations

from hashlib import sha1
from pathlib import Path

_HERE = Path(__file__).parent
# geometry and scene, tasks and their initial states, the scripted expert and play, the observation layout
SOURCES = (
    "layout.py",
    "scene.py",
    "tasks.py",
    "predicates.py",
    "sampling.py",
    "primitives.py",
    "expert.py",
    "play.py",
    "collect.py",
    "observations.py",
)


def kitchen_fingerprint(folder: Path = _HERE) -> str:
    """12 hex digits; any edit of a source file or an MJCF asset changes it (comments included: stricter is safer)."""
    digest = sha1()
    for path in [*(folder / name for name in SOURCES), *sorted((folder / "assets").glob("*.xml"))]:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]
