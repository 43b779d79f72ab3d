"""Atomic file and folder writes, shared by every stage that publishes something.

A reader (or a later run after a kill) never sees a half-written file or folder, and concurrent writers never share
a temporary name: each write goes to its own temporary file (or `.<name>.tmp-<pid>` folder) beside the target, which
is then renamed into place. Folders left by a run killed before its cleanup (SIGKILL) are removed by the next one.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

_UMASK = os.umask(0o022)  # read once at import (os.umask can only be read by setting it), then restored
os.umask(_UMASK)


PRETRAINED = Path("checkpoints/last/pretrained_model")  # a lerobot-train run's latest checkpoint, in its output_dir


def write_atomic(path: str | Path, write: Callable[[str], None]) -> Path:
    """Call `write(tmp_path)`, then rename the temporary file onto `path` (the parent folder is created). The file
    gets the permissions a plain `open(path, "w")` would give (mkstemp's are owner-only)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix or ".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def read_json(path: str | Path) -> Any:
    """The JSON in `path`; a file cut short (a copy, a disk filled, an edit) is a ValueError naming it."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(
            f"{path} is not valid JSON ({err}): it is truncated or corrupt; restore or regenerate it"
        ) from None


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda tmp: Path(tmp).write_text(text))


def write_json_atomic(path: str | Path, payload: object) -> Path:
    return write_text_atomic(path, json.dumps(payload, indent=2, sort_keys=True))


@contextmanager
def staged_dir(final: str | Path) -> Iterator[Path]:
    """Yield a fresh temporary folder path beside `final` (not created) that replaces `final` when the block
    succeeds and is removed when it fails. Staging folders of earlier runs whose process is gone are removed first."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    for stale in final.parent.glob(f".{final.name}.tmp-*"):
        pid = stale.name.rsplit("-", 1)[-1]
        if pid.isdigit() and not _alive(int(pid)):
            logging.info("removing %s, left by a killed run", stale)
            shutil.rmtree(stale, ignore_errors=True)
    tmp = final.parent / f".{final.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        yield tmp
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def check_replaceable_dir(path: Path, marker: str, hint: str) -> None:
    """`staged_dir` replaces its folder whole, so that folder must be new, empty, or an earlier output of the same
    kind (it holds `marker`): anything else would be deleted with it. `hint` says what to pass instead."""
    if path.exists() and not path.is_dir():
        raise ValueError(f"{path} is a file, not a folder: {hint}")
    if path.is_dir() and any(path.iterdir()) and not (path / marker).is_file():
        raise ValueError(f"{path} already holds other files, which writing there would delete: {hint}")


def check_creatable(path: Path, option: str) -> None:
    """Refuse an output `path` below a file (`--output run.json/x.safetensors`) before any work, not when the
    result is written at the end; `option` names the command-line option."""
    for parent in path.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{option} {path}: {parent} is a file, not a folder; pass a path inside a folder.")
            return


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True
