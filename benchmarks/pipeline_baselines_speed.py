"""CPU cost of LeRobot's baseline policies (ACT, Diffusion) as the pipeline configures them: train ms/step, select_action ms/step.

    python benchmarks/pipeline_baselines_speed.py --root <dataset root> --repo-id <repo id> \
        [--config configs/pipeline/benchmark.yaml] [--batch-size 64] [--eval-batch 10]

Each variant is built the way `lerobot-train` builds it (policy config from the same `policy.<opt>` options as the
pipeline's `baselines:` section, `make_policy` on the dataset's metadata, LeRobot's processors, its optimizer preset)
and timed separately for: one batch from LeRobot's DataLoader (`data`), one optimisation step on a fixed batch
(`update`: forward, backward, grad clip, optimizer step), and `select_action` on `--eval-batch` parallel observations
averaged over 100 consecutive steps (chunked policies only run their network once per `n_action_steps`).
Medians are printed because other processes share the machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import torch
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors

from lerobot_skillret.pipeline.config import PipelineConfig
from lerobot_skillret.pipeline.methods import METHODS

# (name, policy type, options) used when no --config is given; a config's `baselines:` section replaces them.
DEFAULT_VARIANTS: list[tuple[str, str, dict[str, Any]]] = [
    ("act", "act", {}),
    ("diffusion", "diffusion", {}),
]


def policy_kwargs(args: dict[str, Any]) -> dict[str, Any]:
    """{"policy.down_dims": [64, 128]} -> {"down_dims": (64, 128)}: the `policy.` options as config fields."""
    out = {}
    for key, value in args.items():
        if not key.startswith("policy."):
            continue
        out[key.removeprefix("policy.")] = tuple(value) if isinstance(value, list) else value
    return out


def variants_from_config(path: str) -> list[tuple[str, str, dict[str, Any]]]:
    """The config's baseline sections, each with the LeRobot policy type of the method that uses it."""
    cfg = PipelineConfig.from_args(path)
    kinds = {section: m.lerobot_type for m in METHODS.values() if m.lerobot_type for section in m.baselines}
    return [
        (name, kinds[name], {**spec.args, "batch_size": spec.batch_size})
        for name, spec in cfg.baselines.items()
        if name != "act_ft"  # the same network as act_ft_prior
    ]


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1000)
    return statistics.median(times)


def bench(name: str, kind: str, options: dict[str, Any], root: str, repo_id: str, batch: int, eval_batch: int) -> None:
    options = dict(options)
    batch = options.pop("batch_size", None) or batch
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    cfg = make_policy_config(kind, device="cpu", push_to_hub=False, **policy_kwargs(options))
    policy = make_policy(cfg, ds_meta=meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    dataset = LeRobotDataset(repo_id, root=root, delta_timestamps=resolve_delta_timestamps(cfg, meta))
    loader = iter(torch.utils.data.DataLoader(dataset, batch_size=batch, shuffle=True, num_workers=0, drop_last=True))
    data_ms = median_ms(lambda: next(loader), 5)
    fixed = pre(next(loader))
    optimizer = cfg.get_optimizer_preset().build(policy.get_optim_params())
    params = sum(p.numel() for p in policy.parameters())

    def update() -> None:
        policy.train()
        loss, _ = policy.forward(fixed)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 10.0)
        optimizer.step()
        optimizer.zero_grad()

    update()  # warm-up
    update_ms = median_ms(update, 8)

    policy.eval()
    policy.reset()
    frame = dataset.hf_dataset[0]
    obs = {k: frame[k][None].repeat(eval_batch, 1) for k in cfg.input_features}
    obs["task"] = ["task"] * eval_batch

    def act() -> None:
        with torch.inference_mode():
            post(policy.select_action(pre(dict(obs))))

    steps = 100
    start = time.perf_counter()
    for _ in range(steps):
        act()
    select_ms = (time.perf_counter() - start) * 1000 / steps
    print(
        f"{name:14s} params {params / 1e6:5.2f}M  batch {batch}: data {data_ms:6.1f} ms  update {update_ms:7.1f} ms"
        f"  -> {data_ms + update_ms:7.1f} ms/step | select_action (batch {eval_batch}) {select_ms:6.2f} ms/step"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", required=True)
    parser.add_argument("--repo-id", required=True)
    parser.add_argument("--config", help="pipeline YAML whose `baselines:` options are timed")
    parser.add_argument("--batch-size", type=int, default=64, help="used when a variant sets none")
    parser.add_argument("--eval-batch", type=int, default=10, help="parallel envs in lerobot-eval")
    parser.add_argument("--only", nargs="*", help="variant names to time")
    args = parser.parse_args()
    torch.manual_seed(0)
    variants = variants_from_config(args.config) if args.config else DEFAULT_VARIANTS
    if not variants:
        parser.error(
            f"{args.config} has no `baselines:` section: nothing to time (configs/pipeline/benchmark.yaml has one)"
        )
    for name, kind, options in variants:
        if args.only and name not in args.only:
            continue
        bench(name, kind, options, args.root, args.repo_id, args.batch_size, args.eval_batch)


if __name__ == "__main__":
    main()
