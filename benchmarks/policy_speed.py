"""skillret training-step time (cpu and paper configs, both stages) and select_action latency next to LeRobot's ACT.

Training step = the policy's whole forward (including the windows it fetches itself: temporal pairs, prior and
retrieved windows) + backward + Adam step, on low-dim observations shaped like the kitchen's, batches as
lerobot-train gives them (loading the batch itself is not timed). select_action is timed per step on CPU, batch 1,
low-dim, against ACT with LeRobot's default sizes on the same observation (default chunking, and chunk = H).
It also prints where a stage-1 step spends its time and how fast its LSTM kernels run against a dense matmul of the
same size on the same core: the bound on what a faster implementation at the same width can gain in float32; and
stage-1 throughput (windows per second on one core) of the step before 4860f8e (each window's temporal pair encoded
but not trained) against today's, in float32 and with `--policy.use_amp=true` (bf16 autocast, as lerobot-train's
Accelerator runs it) at batch 64 and 128, the settings timed in alternation in one run.

Run: `.venv/bin/python benchmarks/policy_speed.py` (~2-4 min on 2 cores; `--skip-paper` for ~1 min).
On a GPU, `--device cuda` times the training steps of both configs there instead (float32 and bf16 autocast, the
configs' batches and larger ones, as windows per second), the numbers to size a GPU run by.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.utils.feature_utils import dataset_to_policy_features

from lerobot_skillret.data.fingerprint import checkpoint_fingerprint, dataset_fingerprint
from lerobot_skillret.data.retrieval_file import RetrievalResult
from lerobot_skillret.policy.configuration_skillret import SkillRetConfig
from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from synthetic import make_synthetic_dataset

STATE_DIM, ENV_DIM, ACTION_DIM = 20, 13, 7  # like the kitchen observations
CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "policy"


def _parse() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (1 is stable when shared)")
    parser.add_argument("--skip-paper", action="store_true", help="skip the GPU-scale paper config (slow on CPU)")
    parser.add_argument("--act-steps", type=int, default=300, help="select_action steps timed per policy")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds of the stage-1 throughput settings")
    parser.add_argument("--device", default="cpu", help="cpu (all sections) or cuda (training steps on the GPU)")
    return parser.parse_args()


def policy_fields(name: str) -> dict:
    """The `policy` section of configs/policy/<name>.json (one source of truth for the sizes)."""
    fields = json.loads((CONFIGS / f"{name}.json").read_text())["policy"]
    fields.pop("type")
    return {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()}


def make_policy(fields: dict, root: Path, repo_id: str, device: str = "cpu", **overrides) -> SkillRetPolicy:
    config = SkillRetConfig(**{**fields, **overrides, "device": device, "push_to_hub": False})
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    return SkillRetPolicy(config, dataset_stats=meta.stats, dataset_meta=meta).to(device)


def batches(policy: SkillRetPolicy, root: Path, repo_id: str, batch_size: int, count: int) -> list[dict]:
    config, fps = policy.config, LeRobotDatasetMetadata(repo_id, root=root).fps
    deltas = None  # `fast_windows`: anchor frames only; the policy gathers the windows (timed in its forward)
    if config.observation_delta_indices is not None:
        deltas = {k: [i / fps for i in config.observation_delta_indices] for k in config.input_features}
        deltas["action"] = [i / fps for i in config.action_delta_indices]
    loader = torch.utils.data.DataLoader(
        LeRobotDataset(repo_id, root=root, delta_timestamps=deltas), batch_size=batch_size, shuffle=True, drop_last=True
    )
    if len(loader) == 0:
        raise ValueError(f"batch {batch_size} is larger than {root}'s {len(loader.dataset)} frames")
    out: list[dict] = []
    while len(out) < count:
        out.extend(batch for batch, _ in zip(loader, range(count - len(out)), strict=False))
    device = config.device  # where lerobot-train's preprocessor would put the batch
    return [{k: v.to(device) if isinstance(v, torch.Tensor) else v for k, v in batch.items()} for batch in out]


def optimizer_of(policy: SkillRetPolicy, old: bool = False) -> torch.optim.Optimizer:
    """The optimizer lerobot-train builds from the policy's preset (fused Adam), or (`old`) the per-tensor Adam of
    LeRobot's `adam` preset that skillret used before it."""
    params = policy.get_optim_params()
    return torch.optim.Adam(params) if old else policy.config.get_optimizer_preset().build(params)


def time_training(
    policy: SkillRetPolicy,
    data: list[dict],
    warmup: int = 2,
    amp: bool = False,
    loss_of: Callable | None = None,
    old_optimizer: bool = False,
) -> float:
    """Median seconds per forward + backward + Adam step (`amp`: the forward under bf16 autocast, as lerobot-train
    runs it with `--policy.use_amp=true` on CPU; `loss_of(batch)`: another loss than `policy.forward`;
    `old_optimizer`: see `optimizer_of`)."""
    optimizer = optimizer_of(policy, old_optimizer)
    policy.train()
    device = torch.device(policy.config.device)
    sync = torch.cuda.synchronize if device.type == "cuda" else lambda: None
    times = []
    for i, batch in enumerate(data):
        sync()
        start = time.perf_counter()
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            loss, _ = (loss_of or policy.forward)(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        sync()
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def lstm_flops(policy: SkillRetPolicy, batch: dict) -> int:
    """Floating-point operations of every nn.LSTM in one training step: the forward's multiply-adds
    (2 * 4h * (in + h) per row, step and layer), counted from the shapes each LSTM sees, and a backward taken as
    twice the forward (gradients for inputs and weights)."""
    total = 0

    def count(module: torch.nn.LSTM, inputs: tuple) -> None:
        nonlocal total
        rows, steps = inputs[0].shape[:2]
        width, hidden = module.input_size, module.hidden_size
        for layer in range(module.num_layers):
            total += 2 * 4 * hidden * ((width if layer == 0 else hidden) + hidden) * rows * steps

    lstms = [m for m in policy.modules() if isinstance(m, torch.nn.LSTM)]
    hooks = [m.register_forward_pre_hook(count) for m in lstms]
    try:
        policy.forward(batch)
    finally:
        for hook in hooks:
            hook.remove()
    return 3 * total


def matmul_gflops(rows: int = 1280, inner: int = 263, cols: int = 512, repeats: int = 200) -> float:
    """GFLOP/s of a float32 matmul shaped like an LSTM layer's input projection: what this core attains on dense
    work of that size (the yardstick for the LSTM kernels)."""
    a, b = torch.randn(rows, inner), torch.randn(inner, cols)
    for _ in range(10):
        a @ b
    start = time.perf_counter()
    for _ in range(repeats):
        a @ b
    return 2 * rows * inner * cols * repeats / (time.perf_counter() - start) / 1e9


def stage1_breakdown(policy: SkillRetPolicy, data: list[dict]) -> None:
    """Where a stage-1 step spends its time (torch.profiler, self CPU time) and how fast its LSTM kernels run.

    Why: the step is bounded by the LSTMs' arithmetic when their kernels already run near what the core attains on a
    dense matmul; then only less LSTM work per window (or other hardware) makes it faster."""
    from torch.profiler import ProfilerActivity, profile

    optimizer = optimizer_of(policy)
    policy.train()

    def step(batch: dict) -> None:
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    for batch in data[:2]:
        step(batch)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for batch in data[2:]:
            step(batch)
    groups = {"LSTM kernels (oneDNN rnn, fwd + bwd)": "rnn", "matmuls (MLP heads, encoders)": "mm", "Adam": "Adam"}
    shares = dict.fromkeys(groups, 0.0)
    total = sum(e.self_cpu_time_total for e in prof.key_averages())
    for event in prof.key_averages():
        name = event.key
        if "rnn" in name or "lstm" in name:
            shares["LSTM kernels (oneDNN rnn, fwd + bwd)"] += event.self_cpu_time_total
        elif name in ("aten::mm", "aten::addmm", "aten::bmm"):
            shares["matmuls (MLP heads, encoders)"] += event.self_cpu_time_total
        elif (
            "adam" in name.lower()
            or name.startswith("aten::_foreach")
            or name in ("aten::addcdiv_", "aten::lerp_", "aten::sqrt")
        ):
            shares["Adam"] += event.self_cpu_time_total
    steps = len(data) - 2
    print("\n== where a stage-1 step (cpu config, batch 64) spends its time ==")
    for label, value in shares.items():
        print(f"{label:>38}: {100 * value / total:5.1f} %")
    print(f"{'the rest (autograd, gathers, pointwise)':>38}: {100 * (total - sum(shares.values())) / total:5.1f} %")
    lstm_s = shares["LSTM kernels (oneDNN rnn, fwd + bwd)"] / 1e6 / steps
    achieved = lstm_flops(policy, data[0]) / lstm_s / 1e9
    attainable = matmul_gflops()
    print(
        f"LSTM kernels: {1e3 * lstm_s:.1f} ms per step at {achieved:.1f} GFLOP/s; a float32 matmul of an LSTM layer's "
        f"size on this core: {attainable:.1f} GFLOP/s ({100 * achieved / attainable:.0f} % of it)"
    )


def pairs_encoded_only(policy: SkillRetPolicy) -> Callable:
    """The stage-1 loss before 4860f8e, for the side-by-side ratio: every window of the batch an anchor, its
    temporal pair encoded for the temporal term only (2B encoder rows and B decoder rows per B trained windows;
    today's step trains B/2 anchors and their pairs: B and B)."""

    def loss_of(batch: dict) -> tuple[torch.Tensor, dict]:
        anchors = batch["index"].reshape(-1)
        data = policy._data(anchors)
        loss, terms, _ = policy._skill_loss([(data.own.gather(anchors, policy.config.device), data.own)])
        return loss, terms

    return loss_of


def stage1_throughput(prior: Path, rounds: int) -> None:
    """Stage-1 windows per second on one core: the step before 4860f8e (float32, batch 64, the benchmark's, with
    the per-tensor Adam of then) against today's (float32; the same with the old Adam, to show each change's part;
    and bf16 autocast `--policy.use_amp=true` at batch 64 and 128), alternated for `rounds` rounds so that a machine
    shared with other work slows every setting alike; medians and their ratios to the step before.

    Why these: the step is bound by the LSTMs' float32 arithmetic (see the breakdown), so it gets faster only with
    less LSTM work per trained window (today's step no longer encodes pairs it does not train), less work around
    the LSTMs (the fused Adam) or cheaper arithmetic: oneDNN runs bf16 kernels faster on AVX512-BF16 / AMX cores,
    and a bigger batch then pays (in float32 it does not: the kernels are already near the core's matmul rate)."""
    before = "before 4860f8e: float32, batch 64"
    settings = {  # name: (batch, bf16 autocast, the step before, per-tensor Adam)
        before: (64, False, True, True),
        "today's step, old Adam: float32": (64, False, False, True),
        "today: float32, batch 64": (64, False, False, False),
        "today: bf16 autocast, batch 64": (64, True, False, False),
        "today: bf16 autocast, batch 128": (128, True, False, False),
    }
    policy = make_policy(policy_fields("cpu"), prior, "bench/prior")
    data = {size: batches(policy, prior, "bench/prior", size, 10) for size, *_ in settings.values()}
    rates: dict[str, list[float]] = {name: [] for name in settings}
    for _ in range(rounds):
        for name, (size, amp, old_step, old_adam) in settings.items():
            loss_of = pairs_encoded_only(policy) if old_step else None
            rate = size / time_training(policy, data[size], amp=amp, loss_of=loss_of, old_optimizer=old_adam)
            rates[name].append(rate)
    base = statistics.median(rates[before])
    print(f"\n== stage-1 throughput on one core (cpu config, {rounds} alternating rounds; median) ==")
    for name, values in rates.items():
        rate = statistics.median(values)
        print(f"{name:>33}: {rate:6.0f} windows/s   x{rate / base:.2f}   (rounds: {min(values):.0f}-{max(values):.0f})")
    cpuinfo = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    native = "yes" if "avx512_bf16" in cpuinfo or "amx_bf16" in cpuinfo else "no (or unknown)"
    print(f"bf16 instructions on this CPU: {native}; without them bf16 is emulated and use_amp does not pay")


def time_select_action(policy, observations: list[dict]) -> float:
    """Mean seconds per select_action call over an episode-like sequence (reset first)."""
    policy.reset()
    with torch.no_grad():
        for obs in observations[:20]:
            policy.select_action(obs)
        policy.reset()
        start = time.perf_counter()
        for obs in observations:
            policy.select_action(obs)
    return (time.perf_counter() - start) / len(observations)


def stage2_policy(fields: dict, prior: Path, target: Path, work: Path, device: str = "cpu") -> SkillRetPolicy:
    """Stage 2 with prior fine-tuning and retrieval of 10% of the prior frames (random anchors here)."""
    stage1 = make_policy(fields, prior, "bench/prior")
    folder = work / f"stage1-{len(list(work.iterdir()))}"
    stage1.save_pretrained(folder)
    frames = LeRobotDatasetMetadata("bench/prior", root=prior).total_frames
    index = torch.randperm(frames)[: frames // 10]
    path = RetrievalResult(
        prior_index=index,
        distance=torch.zeros(len(index)),
        latent=torch.randn(len(index), fields["latent_dim"]),
        checkpoint_fingerprint=checkpoint_fingerprint(folder),
        prior_fingerprint=dataset_fingerprint(prior),
        target_fingerprint=dataset_fingerprint(target),
    ).save(work / f"retrieval-{folder.name}.safetensors")
    policy = make_policy(
        fields,
        target,
        "bench/target",
        device,
        stage="policy",
        prior_repo_id="bench/prior",
        prior_root=str(prior),
        retrieval_path=str(path),
    )
    policy.load_state_dict(stage1.state_dict())
    policy.config.pretrained_path = folder
    return policy


def gpu_steps(prior: Path, target: Path, work: Path, device: str, skip_paper: bool) -> None:
    """Training steps of both configs on a GPU: ms per step and windows per second, float32 and bf16 autocast,
    at the config's batch and larger ones (on a GPU a bigger batch is nearly free until the device fills)."""
    print(f"device: {torch.cuda.get_device_name(device) if device.startswith('cuda') else device}")
    print("\n== training step on the GPU (forward + backward + Adam; median of 10 after 3 warm-up steps) ==")
    for name in ("cpu", *(() if skip_paper else ("paper",))):
        fields = policy_fields(name)
        for batch_size in (16, 64, 256, 1024):
            one = make_policy(fields, prior, "bench/prior", device)
            two = stage2_policy(fields, prior, target, work, device)
            data1 = batches(one, prior, "bench/prior", batch_size, 13)
            data2 = batches(two, target, "bench/target", batch_size, 13)
            for amp in (False, True):
                t1, t2 = time_training(one, data1, 3, amp), time_training(two, data2, 3, amp)
                print(
                    f"{name:>6} config, batch {batch_size:4d}, {'bf16' if amp else 'fp32'}: stage 1 {1e3 * t1:7.1f} "
                    f"ms/step ({batch_size / t1:7.0f} windows/s)   stage 2 {1e3 * t2:7.1f} ms/step",
                    flush=True,
                )


def main() -> None:
    args = _parse()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        dims = dict(state_dim=STATE_DIM, env_dim=ENV_DIM, action_dim=ACTION_DIM)
        prior = make_synthetic_dataset(work / "prior", "bench/prior", num_episodes=8, min_len=150, max_len=250, **dims)
        target = make_synthetic_dataset(  # 8 episodes on a GPU: its largest batch (1,024) needs that many frames
            work / "target",
            "bench/target",
            num_episodes=4 if args.device == "cpu" else 8,
            min_len=150,
            max_len=250,
            seed=1,
            **dims,
        )
        (work / "ckpt").mkdir()
        print(f"torch threads: {torch.get_num_threads()}; obs: state {STATE_DIM} + env {ENV_DIM}, action {ACTION_DIM}")
        if args.device != "cpu":
            gpu_steps(prior, target, work / "ckpt", args.device, args.skip_paper)
            return
        print("\n== training step (forward + backward + Adam; median) ==")
        for name in ("cpu", *(() if args.skip_paper else ("paper",))):
            fields = policy_fields(name)
            batch_size = {"cpu": 64, "paper": 16}[name]
            steps = 8 if name == "paper" else 15
            one = make_policy(fields, prior, "bench/prior")
            t1 = time_training(one, batches(one, prior, "bench/prior", batch_size, steps))
            two = stage2_policy(fields, prior, target, work / "ckpt")
            t2 = time_training(two, batches(two, target, "bench/target", batch_size, steps))
            print(
                f"{name:>6} config, batch {batch_size}: stage 1 {1e3 * t1:7.1f} ms/step   stage 2 {1e3 * t2:7.1f} ms/step"
            )

        cpu = make_policy(policy_fields("cpu"), prior, "bench/prior")
        stage1_breakdown(cpu, batches(cpu, prior, "bench/prior", 64, 8))
        stage1_throughput(prior, args.rounds)

        print("\n== select_action latency (CPU, batch 1, low-dim; mean per step) ==")
        skill = make_policy(policy_fields("cpu"), prior, "bench/prior").eval()
        generator = torch.Generator().manual_seed(0)
        observations = [
            {
                k: torch.randn(1, *skill.config.input_features[k].shape, generator=generator)
                for k in skill.observation_keys
            }
            for _ in range(args.act_steps)
        ]
        rows = [("skillret (cpu config)", time_select_action(skill, observations))]
        for label, act_overrides in (
            ("ACT default (chunk 100)", {}),
            (
                f"ACT default, chunk {skill.config.horizon}",
                {"chunk_size": skill.config.horizon, "n_action_steps": skill.config.horizon},
            ),
        ):
            act_config = ACTConfig(device="cpu", push_to_hub=False, **act_overrides)
            act_config.input_features = dict(skill.config.input_features)
            act_config.output_features = dict(skill.config.output_features)
            act = ACTPolicy(act_config).eval()
            rows.append((label, time_select_action(act, observations)))
        for label, seconds in rows:
            print(f"{label:>28}: {1e3 * seconds:7.3f} ms/step")


if __name__ == "__main__":
    main()
