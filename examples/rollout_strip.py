"""Turn one `lerobot-eval` rollout video into a strip of frames, for a README or an issue.

Picks the episode with the most subtask progress by default (from the eval folder's eval_info.json), so a failed
evaluation still shows how far the policy got.

    python examples/rollout_strip.py outputs/demo/eval/skillret/open_drawer/seed0/step2000 \\
        --output outputs/demo/rollout_strip.png --frames 8
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import av
import numpy as np


def best_episode(eval_dir: Path) -> tuple[Path, float]:
    """(video, max reward) of the filmed episode that got furthest (largest fraction of the goals unmet at reset)."""
    metrics = json.loads((eval_dir / "eval_info.json").read_text())["per_task"][0]["metrics"]
    filmed = [(r, Path(p)) for r, p in zip(metrics["max_rewards"], metrics["video_paths"], strict=False)]
    if not filmed:
        raise SystemExit(f"{eval_dir} has no videos (lerobot-eval films the first 10 episodes)")
    reward, path = max(filmed, key=lambda item: item[0])
    return path, reward


def read_frames(video: Path) -> list[np.ndarray]:
    with av.open(str(video)) as container:
        return [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("eval_dir", type=Path, help="a lerobot-eval output folder (holds eval_info.json and videos/)")
    parser.add_argument("--output", type=Path, required=True, help="PNG to write")
    parser.add_argument("--frames", type=int, default=8, help="frames in the strip, evenly spaced (default 8)")
    parser.add_argument("--video", type=Path, help="a specific episode video instead of the best one")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    video, reward = (args.video, float("nan")) if args.video else best_episode(args.eval_dir)
    frames = read_frames(video)
    picks = np.linspace(0, len(frames) - 1, args.frames).round().astype(int)
    fig, axes = plt.subplots(1, len(picks), figsize=(1.8 * len(picks), 2.1))
    for ax, index in zip(np.atleast_1d(axes), picks, strict=True):
        ax.imshow(frames[index])
        ax.set_title(f"frame {index}", fontsize=7)
        ax.axis("off")
    where = "/".join(args.eval_dir.resolve().parts[-4:])  # <method>/<task>/seed<s>/step<n> in a pipeline run
    fig.suptitle(f"{where}: {video.stem}, subtask progress {reward:.2f}")
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.output.with_name(f".{args.output.stem}.tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(args.output)
    print(f"wrote {args.output} from {video} ({len(frames)} frames)")


if __name__ == "__main__":
    main()
