"""Render every kitchen task's initial scene into one PNG grid (examples/images/kitchen_tasks.png).

MUJOCO_GL=egl python examples/render_tasks.py [--size 256] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")


def main() -> None:
    from PIL import Image, ImageDraw

    from lerobot_skillret.kitchen.expert import reset_scene
    from lerobot_skillret.kitchen.rendering import CameraRenderer
    from lerobot_skillret.kitchen.scene import KitchenScene
    from lerobot_skillret.kitchen.tasks import TASKS

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "images" / "kitchen_tasks.png")
    args = parser.parse_args()
    scene = KitchenScene(render_collision_mesh=False)
    renderer = CameraRenderer(scene, args.size)
    tiles = []
    for name, task in TASKS.items():
        reset_scene(scene, task, np.random.default_rng(args.seed))
        tile = Image.fromarray(renderer.render("overview"))
        ImageDraw.Draw(tile).text((6, 4), name, fill=(0, 0, 0))
        tiles.append(tile)
    grid = Image.new("RGB", (args.size * len(tiles), args.size))
    for i, tile in enumerate(tiles):
        grid.paste(tile, (i * args.size, 0))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp.png")
    grid.save(tmp, optimize=True)
    tmp.replace(args.out)
    renderer.close()
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
