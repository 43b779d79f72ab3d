"""Optional per-frame primitive labels: the `primitive_index` column and the names of its values.

Any dataset may carry them (the kitchen's play data does); retrieval reports use them to say which behaviours were
retrieved. The names live in `meta/primitives.json` (a JSON list, value i -> name i) or, for datasets made
elsewhere, in `meta/info.json` under features.primitive_index.names.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from lerobot_skillret.files import read_json, write_text_atomic

PRIMITIVE_KEY = "primitive_index"
NAMES_FILE = "meta/primitives.json"


def write_label_names(root: str | Path, names: Sequence[str]) -> None:
    write_text_atomic(Path(root) / NAMES_FILE, json.dumps([str(name) for name in names]))


def load_label_names(root: str | Path) -> list[str] | None:
    """Names of the `primitive_index` values, or None when the dataset does not state them (reports then say
    "primitive <i>")."""
    path = Path(root) / NAMES_FILE
    if path.is_file():
        names = read_json(path)
        return [str(n) for n in names] if isinstance(names, list) else None
    info = Path(root) / "meta" / "info.json"
    if info.is_file():
        names = read_json(info).get("features", {}).get(PRIMITIVE_KEY, {}).get("names")
        if isinstance(names, list) and len(names) > 1 and all(isinstance(n, str) for n in names):
            return names
    return None
