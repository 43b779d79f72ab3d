"""`skillret-generate`: write kitchen play data or task demonstrations as a local LeRobotDataset (v3.0).

Episodes are simulated in worker processes (seeded per episode, so the output depends only on --seed and the
sizes, not on --workers) and written by this process into a temporary folder renamed into place at the end:
an interrupted run leaves no dataset behind. Besides the LeRobot files the dataset root holds
`meta/primitives.json` (the names of the `primitive_index` values) and `meta/kitchen.json`: frames per primitive,
successful calls of each built-in task's plan step (play), per-episode task, seed, success and initial MuJoCo
state (for exact replays), and the generator settings.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import multiprocessing as mp
import multiprocessing.connection as mp_connection
import os
import signal
import sys
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing.connection import Connection
from pathlib import Path

from tqdm import tqdm

from lerobot_skillret.data.labels import write_label_names
from lerobot_skillret.files import check_creatable, check_replaceable_dir, staged_dir
from lerobot_skillret.kitchen import observations as O
from lerobot_skillret.kitchen.collect import PLAY_TASK_TEXT, Episode, EpisodeJob, episode_jobs, run_episode
from lerobot_skillret.kitchen.layout import CONTROL_FREQ
from lerobot_skillret.kitchen.play import plan_coverage
from lerobot_skillret.kitchen.primitives import PRIMITIVES
from lerobot_skillret.kitchen.tasks import TASKS

DEFAULT_PLAY_EPISODES = 150
DEFAULT_PLAY_STEPS = 2000
DEFAULT_DEMOS = 30
DEFAULT_WORKERS = 2
PREFETCH = 2  # jobs started per worker ahead of the next episode due: keeps workers busy, bounds waste
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _write_episode(dataset, episode: Episode, task_text: str) -> None:
    n = len(episode.frames["action"])
    for i in range(n):
        frame = {key: values[i] for key, values in episode.frames.items()}
        frame["task"] = task_text
        dataset.add_frame(frame)
    dataset.save_episode()


def _worker(conn: Connection, simulate: Callable[[EpisodeJob], Episode]) -> None:
    """Worker process: simulate each `(position, job)` received, send back `(position, episode or error)`."""
    if sys.platform.startswith("linux"):  # the kernel kills this worker when the generator dies, even by SIGKILL
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() == 1:  # the generator died before prctl took effect
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the generator's to handle
    while True:
        try:
            position, job = conn.recv()
        except EOFError:  # the generator closed the pipe: done
            return
        try:
            conn.send((position, simulate(job), None))
        except Exception:
            conn.send((position, None, traceback.format_exc()))


class GenerationError(RuntimeError):
    """Generation cannot finish (the expert keeps failing, a worker crashed): reported as one line by the CLI."""


@contextmanager
def _episode_stream(
    jobs: list[EpisodeJob], workers: int, simulate: Callable[[EpisodeJob], Episode] | None = None
) -> Iterator[Iterator[Episode]]:
    """Episodes in job order, simulated by `workers` spawned processes (0: in this process, for tests).

    Each worker owns one pipe and holds one job at a time; no more than `workers * PREFETCH` jobs are ever started
    ahead of the next episode due, so early stops (demos stop at the requested number of successes, with most of
    the `episodes * 3` attempts never needed) waste little. Leaving the block kills the workers. There is no shared
    queue, lock or handler thread: `multiprocessing.Pool.terminate()` can deadlock when a worker is still writing a
    large episode into the shared result queue, and a killed worker can leave that queue's lock held.
    """
    simulate = simulate or run_episode  # looked up now, so tests can patch the module's run_episode
    if workers == 0:
        yield map(simulate, jobs)
        return
    ctx = mp.get_context("spawn")
    conns, procs = [], []
    try:
        for _ in range(min(workers, len(jobs))):
            conn, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(child, simulate), daemon=True)
            proc.start()
            child.close()
            conns.append(conn)
            procs.append(proc)
        yield _ordered(jobs, conns)
    finally:
        for proc in procs:
            proc.kill()
        for proc in procs:
            proc.join()
        for conn in conns:
            conn.close()


def _ordered(jobs: list[EpisodeJob], conns: list[Connection]) -> Iterator[Episode]:
    """Hand jobs to idle workers (at most `len(conns) * PREFETCH` ahead of the next due) and yield in job order."""
    idle, done, next_job = list(conns), {}, 0
    for due in range(len(jobs)):
        while due not in done:
            while idle and next_job < min(len(jobs), due + len(conns) * PREFETCH):
                idle.pop().send((next_job, jobs[next_job]))
                next_job += 1
            for conn in mp_connection.wait([c for c in conns if c not in idle]):
                try:
                    position, episode, error = conn.recv()
                except EOFError:
                    raise GenerationError("a simulation worker died (killed, or crashed in MuJoCo)") from None
                if error is not None:
                    raise GenerationError(f"simulating episode {position} failed in a worker:\n{error}")
                done[position] = episode
                idle.append(conn)
        yield done.pop(due)


def generate(args: argparse.Namespace) -> Path:
    """Generate the dataset described by parsed CLI `args`; returns its root."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(args.root).expanduser().resolve()
    check_creatable(root, "--root")
    check_replaceable_dir(root, "meta/info.json", "choose a new --root (--overwrite only replaces a dataset)")
    if root.exists() and not args.overwrite:
        raise FileExistsError(f"{root} already exists; pass --overwrite or choose another --root")
    features = O.dataset_features(tuple(args.cameras), O.DEFAULT_IMAGE_SIZE)
    jobs = episode_jobs(args.kind, args.seed, args.episodes, args.task, args.steps_per_episode, tuple(args.cameras))
    episodes_meta, attempts, failures, primitive_frames, logs = [], 0, 0, Counter(), []
    with staged_dir(root) as tmp:  # an interrupted run leaves no dataset behind
        dataset = LeRobotDataset.create(
            args.repo_id,
            fps=CONTROL_FREQ,
            features=features,
            root=tmp,
            robot_type="panda",
            use_videos=bool(args.cameras),
        )
        with _episode_stream(jobs, args.workers) as stream:
            bar = tqdm(total=args.episodes, desc=f"{args.kind} episodes", unit="ep")
            for episode in stream:
                attempts += 1
                if args.kind == "demos" and not episode.success:
                    failures += 1
                    continue
                task_text = TASKS[args.task].description if args.kind == "demos" else PLAY_TASK_TEXT
                _write_episode(dataset, episode, task_text)
                primitive_frames.update(PRIMITIVES[int(label[0])] for label in episode.frames[O.PRIMITIVE_KEY])
                logs.append(episode.log)
                episodes_meta.append(
                    {
                        "episode_index": len(episodes_meta),
                        "seed": episode.seed,
                        "scene_task": episode.task,
                        "success": episode.success,
                        "length": len(episode.frames["action"]),
                        "initial_state": episode.initial_state.tolist(),
                        "primitives": [list(map(str, entry)) for entry in episode.log],
                    }
                )
                bar.update(1)
                if len(episodes_meta) == args.episodes:
                    break
            bar.close()
        dataset.finalize()
        if len(episodes_meta) < args.episodes:
            raise GenerationError(
                f"only {len(episodes_meta)} of {args.episodes} successful demos in {attempts} attempts; "
                "the scripted expert is failing, check the task"
            )
        coverage = plan_coverage(logs) if args.kind == "play" else {}
        meta = {
            "kind": args.kind,
            "task": args.task,
            "seed": args.seed,
            "cameras": list(args.cameras),
            "primitive_frames": {name: primitive_frames[name] for name in PRIMITIVES},
            **({"plan_step_calls": coverage} if coverage else {}),
            "attempts": attempts,
            "failed_attempts": failures,
            "episodes": episodes_meta,
        }
        (tmp / O.KITCHEN_META).write_text(json.dumps(meta))
        write_label_names(tmp, PRIMITIVES)
    if args.kind == "demos":
        print(f"{args.task}: kept {len(episodes_meta)} successful demos of {attempts} attempts ({failures} failed)")
    total = max(sum(primitive_frames.values()), 1)
    print("frames per primitive: " + ", ".join(f"{n} {c} ({c / total:.0%})" for n, c in primitive_frames.items()))
    if coverage:
        covered = sum(count > 0 for count in coverage.values())
        fewest = ", ".join(f"{name} {count}" for name, count in list(coverage.items())[:5])
        print(f"built-in plan steps done at least once: {covered} of {len(coverage)}; fewest: {fewest}")
    print(f"wrote {root}")
    return root


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="skillret-generate",
        description="Generate Panda kitchen data as a local LeRobotDataset v3.0: task-agnostic play (prior data) "
        "or scripted demonstrations of one task (target data).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
        "  skillret-generate play --root data/kitchen_play --episodes 150 --steps-per-episode 2000\n"
        "  skillret-generate demos --root data/demos_cook --task cook --episodes 30\n\n"
        "output: a LeRobotDataset v3.0 at --root (data/, meta/, videos/ with --cameras) plus meta/primitives.json\n"
        "(the names of the primitive_index values) and meta/kitchen.json (frames per primitive, per-episode seed,\n"
        "success and initial MuJoCo state).",
    )
    sub = parser.add_subparsers(dest="kind", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--root", "--output", dest="root", required=True, help="dataset folder to create")
    common.add_argument("--repo-id", default=None, help="dataset repo id stored in the metadata (never pushed)")
    common.add_argument("--seed", type=int, default=0, help="base seed; episode i uses a seed derived from it")
    common.add_argument(
        "--workers",
        type=int,
        default=DEFAULT_WORKERS,
        help="simulation worker processes (0: simulate in this process)",
    )
    common.add_argument(
        "--cameras",
        nargs="*",
        default=[],
        choices=O.CAMERAS,
        help="84x84 cameras to record as videos (none: state-only data)",
    )
    common.add_argument(
        "--overwrite", action="store_true", help="replace an existing dataset at --root (never another folder)"
    )
    play = sub.add_parser(
        "play",
        parents=[common],
        help="random primitives from randomised scenes (prior data)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    play.add_argument("--episodes", type=int, default=DEFAULT_PLAY_EPISODES, help="play episodes to write")
    play.add_argument("--steps-per-episode", type=int, default=DEFAULT_PLAY_STEPS, help="frames per play episode")
    demos = sub.add_parser(
        "demos",
        parents=[common],
        help="successful scripted demos of one task (target data)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    demos.add_argument("--task", required=True, choices=sorted(TASKS), help="task to demonstrate")
    demos.add_argument(
        "--episodes", type=int, default=DEFAULT_DEMOS, help="successful demos to keep (failed attempts are dropped)"
    )
    play.set_defaults(task=None)  # both kinds carry every field `generate` reads
    demos.set_defaults(steps_per_episode=0)
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    if args.episodes < 1 or args.workers < 0 or args.seed < 0:
        sys.exit("skillret-generate: --episodes must be >= 1, --workers >= 0 and --seed >= 0")
    if args.kind == "play" and args.steps_per_episode < 1:
        sys.exit("--steps-per-episode must be >= 1")
    if args.repo_id is None:
        args.repo_id = f"local/kitchen_{args.kind}" + (f"_{args.task}" if args.task else "")
    # SIGTERM (a pipeline cancelling this stage, `kill`) unwinds like Ctrl-C: the temporary folder is removed.
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))
    try:
        generate(args)
    except (FileExistsError, ValueError, GenerationError) as e:
        sys.exit(f"skillret-generate: {e}")


if __name__ == "__main__":
    main()
