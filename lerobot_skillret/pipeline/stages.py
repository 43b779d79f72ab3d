"""Run pipeline stages as subprocesses so that a finished stage is never redone and a killed one leaves no debris.

Each stage's command writes into a `.partial` path; only a command that exits 0 gets its partial path renamed to
the final artifact. Re-running the pipeline skips every stage whose artifact exists and restarts any other from
scratch, so killing the pipeline at any moment loses at most the stage in flight.

Several pipeline processes may share one output folder (e.g. one per CPU core, each with its own methods): a stage
is built under an exclusive file lock, so a second process waits for it and then skips it.
"""

from __future__ import annotations

import fcntl
import logging
import os
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from lerobot_skillret.files import read_json, write_json_atomic

log = logging.getLogger("skillret.pipeline")


@dataclass
class Stage:
    """One step of the pipeline: `command` writes `partial`, which becomes `output` when the command succeeds."""

    name: str
    output: Path
    command: list[str] = field(default_factory=list)
    after: Callable[[Path], None] | None = None  # runs on the partial artifact before it is published
    # what else the artifact depends on (e.g. the kitchen's fingerprint): recorded and checked with the command
    tags: tuple[str, ...] = ()

    @property
    def identity(self) -> list[str]:
        return [*self.command, *self.tags]

    def same_build(self, recorded: list[str]) -> bool:
        """Whether `recorded` (an identity from commands.json) builds what this stage would.

        A `--config_path` is compared by file name only: its contents are in the tags, so the same file read from
        another checkout (a moved or second clone of the repository) is still the same build.
        """
        return _located(recorded) == _located(self.identity)

    @property
    def partial(self) -> Path:
        return self.output.with_name(self.output.name + ".partial")

    def done(self) -> bool:
        return self.output.exists()


def _located(identity: list[str]) -> list[str]:
    """`identity` with each `--config_path=<dir>/<name>` reduced to its name."""
    flag = "--config_path="
    return [flag + Path(t.removeprefix(flag)).name if t.startswith(flag) else t for t in identity]


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


class Cancelled(RuntimeError):
    """A stage was not started because another job of the same pipeline run failed or was interrupted."""


@contextmanager
def file_lock(path: Path, what: str = "") -> Iterator[int]:
    """Exclusive advisory lock on `path` (created if missing); yields its file descriptor.

    Pass the descriptor to a child process (`pass_fds`) to keep the lock held until the child exits as well, even
    if this process is killed first. Logs a line when the lock is busy, so a waiting job is not silent.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log.info("[wait] %s is being built by another job", what or path)
            fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield handle.fileno()
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


class StageRunner:
    """Runs stages with logs under `<output_dir>/logs/` and wall times in `<output_dir>/timings.json`.

    Thread-safe: jobs of one pipeline run share a runner. A failed stage sets `cancel` before releasing its lock;
    once it is set (a stage or job failed, Ctrl-C, SIGTERM) no further stage starts, so a failure is never retried by
    a job that was waiting for the same stage.
    """

    def __init__(self, output_dir: Path, env: dict[str, str] | None = None) -> None:
        self.output_dir = output_dir
        self.logs = output_dir / "logs"
        self.timings_path = output_dir / "timings.json"
        self.commands_path = output_dir / "commands.json"  # the command that built each finished stage
        self.env = {**os.environ, **(env or {})}
        self.cancel = threading.Event()
        self._running: set[subprocess.Popen] = set()  # stage commands in flight, for `terminate`
        self._running_lock = threading.RLock()  # re-entered when SIGTERM lands while the main thread holds it
        self._terminated = False  # set by `terminate` only (a failed job also sets `cancel`, but stops nothing)

    def terminate(self) -> None:
        """Start no further stage and stop the commands in flight (SIGTERM); the next run redoes their stages."""
        self.cancel.set()
        with self._running_lock:
            self._terminated = True
            for child in self._running:
                child.terminate()

    def stop_on_sigterm(self) -> None:
        """Make SIGTERM (`kill`, `timeout`, a job scheduler) stop the run as Ctrl-C does. Without it the pipeline
        died alone and its stage commands ran on, orphaned, for hours (their work thrown away by the next run).
        Main thread only (Python delivers signals there)."""

        def handler(signum: int, frame: object) -> None:
            self.terminate()
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, handler)

    def log_path(self, stage: Stage) -> Path:
        """Where the stage's command writes its stdout and stderr."""
        return self.logs / (stage.name.replace("/", "__") + ".log")

    def _record(self, path: Path, name: str, value: object) -> None:
        with file_lock(path.with_name(f".{path.stem}.lock"), path.name):
            entries = read_json(path) if path.exists() else {}
            entries[name] = value
            write_json_atomic(path, entries)

    def check_built(self, stage: Stage) -> None:
        """An artifact built by another command (the config changed since), or from other inputs than its command
        names (its tags: e.g. the kitchen's files changed since), must not be reused silently."""
        built = read_json(self.commands_path).get(stage.name) if self.commands_path.exists() else None
        if built is not None and not stage.same_build(built):
            changed = sorted(set(stage.identity) ^ set(built))
            raise RuntimeError(
                f"stage {stage.name}: {stage.output} was built with other options or inputs than this run has "
                f"(differing: {changed}). Delete {stage.output} to rebuild it (and what was built from it), or use "
                "another output_dir."
            )

    def timing(self, name: str) -> float | None:
        if not self.timings_path.exists():
            return None
        return read_json(self.timings_path).get(name)

    def run(self, stage: Stage) -> bool:
        """Run `stage` unless its artifact exists (perhaps built by another process meanwhile); True if it ran."""
        with file_lock(stage.output.with_name(f".{stage.output.name}.lock"), stage.name) as lock_fd:
            try:
                return self._run_locked(stage, lock_fd)
            except Cancelled:
                raise
            except BaseException:
                self.cancel.set()  # before the lock is released: a job waiting for this stage must not retry it
                raise

    def _run_locked(self, stage: Stage, lock_fd: int) -> bool:
        if self.cancel.is_set():
            raise Cancelled(f"stage {stage.name} not started: another job of this run failed or was interrupted")
        if stage.done():
            self.check_built(stage)
            log.info("[skip] %s (exists: %s)", stage.name, stage.output)
            return False
        _remove(stage.partial)
        stage.output.parent.mkdir(parents=True, exist_ok=True)
        self.logs.mkdir(parents=True, exist_ok=True)
        log_path = self.log_path(stage)
        log.info("[run ] %s  (log: %s)", stage.name, log_path)
        start = time.monotonic()
        with log_path.open("w") as handle:
            handle.write("$ " + " ".join(stage.command) + "\n")
            handle.flush()
            # the child inherits the lock, so a killed pipeline cannot free it while the child still writes
            with subprocess.Popen(
                stage.command, stdout=handle, stderr=subprocess.STDOUT, env=self.env, pass_fds=(lock_fd,)
            ) as child:
                with self._running_lock:
                    self._running.add(child)
                    if self._terminated:  # terminated between the check above and the start
                        child.terminate()
                try:
                    code = child.wait()
                finally:
                    with self._running_lock:
                        self._running.discard(child)
        seconds = time.monotonic() - start
        if code != 0 and self._terminated:
            raise Cancelled(f"stage {stage.name} stopped: the run was interrupted (the next run redoes it)")
        if code != 0 or not stage.partial.exists():
            tail = "".join(log_path.read_text().splitlines(keepends=True)[-25:])
            why = f"exit code {code}" if code != 0 else f"it did not write {stage.partial}"
            raise RuntimeError(f"stage {stage.name} failed ({why}). Last lines of {log_path}:\n{tail}")
        if stage.after is not None:
            stage.after(stage.partial)
        # the command is recorded first: an output never exists without the record `check_built` reads
        self._record(self.commands_path, stage.name, stage.identity)
        os.replace(stage.partial, stage.output)
        self._record(self.timings_path, stage.name, round(seconds, 1))
        log.info("[done] %s in %.0f s", stage.name, seconds)
        return True
