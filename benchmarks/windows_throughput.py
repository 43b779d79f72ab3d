"""Windows per second: `WindowSampler` vs `LeRobotDataset.__getitem__` with delta_timestamps (same data, same F/H).

Writes (or reuses) a synthetic LeRobotDataset of realistic size with LeRobot's own writer, exports its columns
once with `EpisodeColumns`, then times:
  - LeRobotDataset.__getitem__ with delta_timestamps for obs deltas -(F-1)..H-1 and action deltas 0..H-1,
  - WindowSampler.sample (uniform anchors + gather) in batches,
  - optionally torchrl 0.14's `Sequence` sample unit over the same memory-mapped columns (`--torchrl`).
Run: `.venv/bin/python benchmarks/windows_throughput.py --torchrl`. The first run writes the dataset under
outputs/benchmarks/ (150 episodes x 200-1000 frames, ~88k frames: ~3 min on 2 cores); later runs reuse it (~30 s).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from tensordict import TensorDict

from lerobot_skillret.data.windows import EpisodeColumns, WindowSampler

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from synthetic import make_synthetic_dataset

REPO = "bench/windows"
STATE_DIM, ENV_DIM, ACTION_DIM = 20, 13, 7  # 40-d frames, like the kitchen observations


def _parse() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, default=None, help="dataset folder (created if absent, else reused)")
    parser.add_argument("--episodes", type=int, default=150)
    parser.add_argument("--min-len", type=int, default=200)
    parser.add_argument("--max-len", type=int, default=1000)
    parser.add_argument("--history", type=int, default=10, help="F")
    parser.add_argument("--horizon", type=int, default=10, help="H")
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--batches", type=int, default=400, help="sampler batches to time")
    parser.add_argument("--getitem-calls", type=int, default=300, help="__getitem__ calls to time")
    parser.add_argument("--torchrl", action="store_true", help="also time torchrl's Sequence sample unit")
    return parser.parse_args()


def _rate(count: int, seconds: float) -> str:
    return f"{count / seconds:>14,.0f}"


def _time_getitem(root: Path, fps: int, history: int, horizon: int, calls: int) -> float:
    obs = [d / fps for d in range(-(history - 1), horizon)]
    delta_timestamps = {
        "observation.state": obs,
        "observation.environment_state": obs,
        "action": [d / fps for d in range(horizon)],
    }
    dataset = LeRobotDataset(REPO, root=root, delta_timestamps=delta_timestamps)
    anchors = torch.randint(0, len(dataset), (calls,), generator=torch.Generator().manual_seed(0)).tolist()
    dataset[anchors[0]]  # warm-up: lazy loading
    start = time.perf_counter()
    for i in anchors:
        dataset[i]
    return time.perf_counter() - start


def _time_sampler(sampler: WindowSampler, batch_size: int, batches: int) -> float:
    for _ in range(10):
        sampler.sample(batch_size)
    start = time.perf_counter()
    for _ in range(batches):
        sampler.sample(batch_size)
    return time.perf_counter() - start


def _time_torchrl(sampler: WindowSampler, batch_size: int, batches: int) -> float:
    """torchrl's Sequence unit over the same memmapped columns (needs a per-frame done flag). Before timing,
    check that it yields the same observation windows and pad masks as the WindowSampler on 2,000 anchors."""
    from torchrl.data import RandomSampler, TensorDictReplayBuffer, TensorStorage
    from torchrl.data.replay_buffers import Sequence

    columns, history, horizon = sampler.columns, sampler.history, sampler.horizon
    td = columns.td
    data = TensorDict({k: td[k] for k in sampler.keys}, batch_size=td.batch_size)  # same keys as timed below
    data["next", "done"] = (td["episode_end"] - 1 == torch.arange(len(columns)))[:, None]
    unit = Sequence(length=horizon, burn_in=history - 1, episode_boundary="pad")
    storage = TensorStorage(data)
    buffer = TensorDictReplayBuffer(storage=storage, sampler=RandomSampler(), sample_unit=unit, batch_size=batch_size)
    anchors = sampler.sample_anchors(2000)
    index, info = unit.expand(anchors, {}, storage)
    ours = sampler.gather(anchors)
    steps = history + horizon - 1
    same = torch.equal(
        data["observation.state"][index].reshape(ours["observation.state"].shape), ours["observation.state"]
    )
    same &= torch.equal(~info["validity_mask"].reshape(-1, steps), ours["observation.state_is_pad"])
    print(f"torchrl Sequence windows equal WindowSampler's: {same}")
    for _ in range(3):
        buffer.sample()
    start = time.perf_counter()
    for _ in range(batches):
        buffer.sample()
    return time.perf_counter() - start


def main() -> None:
    args = _parse()
    root = args.root or Path("outputs/benchmarks") / f"windows-{args.episodes}x{args.min_len}-{args.max_len}"
    if not (root / "meta" / "info.json").is_file():
        start = time.perf_counter()
        make_synthetic_dataset(
            root, REPO, args.episodes, args.min_len, args.max_len, STATE_DIM, ENV_DIM, ACTION_DIM, seed=0
        )
        print(f"wrote {root} in {time.perf_counter() - start:.1f} s")
    start = time.perf_counter()
    columns = EpisodeColumns.from_dataset(REPO, root)
    load_s = time.perf_counter() - start
    print(
        f"dataset: {args.episodes} episodes, {len(columns):,} frames, {STATE_DIM + ENV_DIM}-d obs + {ACTION_DIM}-d "
        f"action; F={args.history} H={args.horizon}; torch threads {torch.get_num_threads()}; "
        f"EpisodeColumns.from_dataset {load_s:.2f} s (export on first run, memmap load after)"
    )
    sampler = WindowSampler(columns, args.history, args.horizon, seed=0)
    rows = []
    getitem_s = _time_getitem(root, columns.fps, args.history, args.horizon, args.getitem_calls)
    rows.append(("LeRobotDataset.__getitem__", args.getitem_calls, getitem_s))
    sampler_s = _time_sampler(sampler, args.batch_size, args.batches)
    rows.append((f"WindowSampler.sample({args.batch_size})", args.batch_size * args.batches, sampler_s))
    if args.torchrl:
        torchrl_s = _time_torchrl(sampler, args.batch_size, args.batches // 4)
        rows.append((f"torchrl Sequence ({args.batch_size})", args.batch_size * (args.batches // 4), torchrl_s))

    base = args.getitem_calls / getitem_s
    print(f"\n{'method':<32}{'windows':>10}{'seconds':>10}{'windows/s':>15}{'us/window':>11}{'vs getitem':>12}")
    for name, count, seconds in rows:
        ratio = count / seconds / base
        print(
            f"{name:<32}{count:>10,}{seconds:>10.3f}{_rate(count, seconds)}{seconds / count * 1e6:>11.2f}{ratio:>11,.0f}x"
        )
    print(f"\nWindowSampler / __getitem__ throughput ratio: {args.batch_size * args.batches / sampler_s / base:,.0f}x")


if __name__ == "__main__":
    main()
