"""Is each kitchen task learnable from 30 demonstrations? A converged behaviour-cloning reference says.

A comparison of methods means something only on tasks where imitation is measurable: neither solved by everything
nor by nothing. Per task this script
1. generates the target demonstrations (`skillret-generate demos`, skipped when they exist),
2. reports their statistics (episode lengths, saturated position actions, the gripper label set),
3. trains a BC reference to a plateau on state + environment state (mean/std-normalised), AdamW with cosine
   decay, stopped when the epoch loss has not improved by 2 % over the last 100 epochs (or at --max-epochs, or at
   --max-train-minutes); `--reference` picks the model:
   - `mlp`: an MLP (3 x 512, LayerNorm, GELU) from the current observation to a chunk of 8 future actions, of
     which 4 run before it re-plans;
   - `rnn`: robomimic's BC-RNN, the seed's own target-only baseline (2-layer LSTM, 400 units, sequences of 10,
     batch 100), which remembers the last steps: what a chain needs to tell "just placed" from "about to grasp";
   - `act`: LeRobot's ACT with the benchmark's own settings (`baselines.act.args` of
     configs/pipeline/benchmark.yaml: chunks of 20, re-plans every 10, L1 + KL loss), the same network the
     comparison trains with lerobot-train, here fed from memory instead of LeRobot's data loader (which costs
     ~3 ms per sample) so that it can train to a plateau; `--device cuda` trains it on a GPU;
4. rolls it out from held-out initial states (env seeds from 200,000 up: `kitchen.seeds.CALIBRATION_SEED0`, a range
   no generated dataset and no benchmark evaluation uses, so the tasks are never tuned on the states methods are
   scored on) and reports success, subtask progress and sub-goals completed in a row (per rollout too: steps taken and the goals
   left unmet, to see where it fails).

It is a calibration tool for the benchmark, not one of the compared methods (those are LeRobot's policies and
skillret, run by `skillret-pipeline`; the `act` reference measures what the benchmark's ACT reaches once trained to a
plateau). Results land in `benchmarks/results/learnability/<task>.json` (`bc_rnn/` or `act/` below it for the
others) with the loss curve, one task at a time: a killed run keeps the finished tasks, and a re-run skips them
(--force redoes them). `ladder.png` plots every reference's success against the calibration goals.

    MUJOCO_GL=egl python benchmarks/kitchen_learnability.py --tasks bread_on_plate pan_on_stove
    python benchmarks/kitchen_learnability.py --table     # the markdown table of every stored result
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch
import yaml
from tensordict import TensorDict
from torch import nn

from lerobot_skillret.data.windows import EpisodeColumns
from lerobot_skillret.files import write_atomic, write_json_atomic, write_text_atomic
from lerobot_skillret.kitchen.observations import STATE_NAMES, load_kitchen_meta
from lerobot_skillret.kitchen.seeds import CALIBRATION_SEED0
from lerobot_skillret.kitchen.tasks import TASKS

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "learnability"
OBS_KEYS = ("observation.state", "observation.environment_state")
CHUNK, EXECUTE = 8, 4  # the MLP's action chunk and how much of it runs before re-planning
RNN_HORIZON = 10  # robomimic's BC-RNN sequence length (and the seed's F)
PLATEAU_EPOCHS, PLATEAU_GAIN = 100, 0.02
BENCHMARK_CONFIG = ROOT / "configs" / "pipeline" / "benchmark.yaml"  # the `act` reference's settings


def demo_statistics(columns: EpisodeColumns, root: Path) -> dict:
    meta = load_kitchen_meta(root)  # the generator kept the successful attempts: the expert's success rate
    start = columns.td["episode_start"].as_subclass(torch.Tensor).numpy()
    firsts = np.unique(start)
    lengths = columns.td["episode_end"].as_subclass(torch.Tensor).numpy()[firsts] - firsts
    action = columns.td["action"].as_subclass(torch.Tensor).numpy()
    saturated = (np.abs(action[:, :3]) >= 0.999).mean(axis=0)
    return {
        "expert_success": f"{len(firsts)}/{meta['attempts']}",
        "episodes": len(firsts),
        "frames": len(columns),
        "length_min_median_max": [int(lengths.min()), int(np.median(lengths)), int(lengths.max())],
        "saturated_position_share_xyz": [round(float(x), 3) for x in saturated],
        "gripper_labels": sorted({round(float(g), 2) for g in np.unique(action[:, -1])})[:10],
    }


def frames(columns: EpisodeColumns) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(observations (N, D), actions (N, A), each frame's episode end (N,)) of the demos."""
    td = columns.td
    obs = torch.cat([td[k].as_subclass(torch.Tensor).float() for k in OBS_KEYS], dim=-1)
    return obs, td["action"].as_subclass(torch.Tensor).float(), td["episode_end"].as_subclass(torch.Tensor)


def ahead(end: torch.Tensor, length: int) -> torch.Tensor:
    """(N, length) frame indices t, t+1, ...; steps past an episode's end repeat its last frame (robomimic's padding)."""
    index = torch.arange(len(end))[:, None] + torch.arange(length)[None, :]
    return torch.minimum(index, end[:, None] - 1)


def mse(model: nn.Module, batch: TensorDict) -> torch.Tensor:
    """The MLP's and BC-RNN's loss: MSE between the predicted and the demonstrated (normalised) actions."""
    return (model(batch["obs"]) - batch["target"]).pow(2).mean()


class MLP(nn.Module):
    """The MLP reference: current observation -> a chunk of CHUNK future actions; executes EXECUTE of them."""

    name = "mlp"

    def __init__(self, obs_dim: int, action_dim: int, width: int = 512) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for i in range(3):
            layers += [nn.Linear(obs_dim if i == 0 else width, width), nn.LayerNorm(width), nn.GELU()]
        self.net = nn.Sequential(*layers, nn.Linear(width, CHUNK * action_dim))
        self.action_dim = action_dim

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs).view(-1, CHUNK, self.action_dim)

    @staticmethod
    def examples(obs: torch.Tensor, action: torch.Tensor, end: torch.Tensor) -> TensorDict:
        return TensorDict({"obs": obs, "target": action[ahead(end, CHUNK)]}, batch_size=[len(obs)])

    loss = mse

    def actor(self):
        """A stateful closure: observation (D,) -> the next action; re-plans every EXECUTE steps."""
        queue: list[np.ndarray] = []

        def act(x: torch.Tensor) -> np.ndarray:
            if not queue:
                queue.extend(self(x[None])[0, :EXECUTE].numpy())
            return queue.pop(0)

        return act


class RNN(nn.Module):
    """robomimic's BC-RNN, the seed's target-only baseline: a 2-layer LSTM (400 units) over sequences of RNN_HORIZON
    observations, a linear head to each step's action. In a rollout the hidden state is carried from step to step and
    reset every RNN_HORIZON steps, as robomimic does, so it never runs longer than it was trained for. Unlike robomimic
    (GMM head for human data) the head is deterministic (MSE): the scripted expert is unimodal."""

    name = "rnn"

    def __init__(self, obs_dim: int, action_dim: int, width: int = 400) -> None:
        super().__init__()
        self.lstm = nn.LSTM(obs_dim, width, num_layers=2, batch_first=True)
        self.head = nn.Linear(width, action_dim)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.lstm(obs)[0])

    @staticmethod
    def examples(obs: torch.Tensor, action: torch.Tensor, end: torch.Tensor) -> TensorDict:
        index = ahead(end, RNN_HORIZON)
        return TensorDict({"obs": obs[index], "target": action[index]}, batch_size=[len(obs)])

    loss = mse

    def actor(self):
        memory: dict = {"state": None, "steps": 0}

        def act(x: torch.Tensor) -> np.ndarray:
            if memory["steps"] % RNN_HORIZON == 0:
                memory["state"] = None
            out, memory["state"] = self.lstm(x[None, None], memory["state"])
            memory["steps"] += 1
            return self.head(out)[0, 0].numpy()

        return act


def act_settings() -> dict:
    """The ACT settings the benchmark trains its `act` baseline with (`policy.*` of `baselines.act.args`)."""
    args = yaml.safe_load(BENCHMARK_CONFIG.read_text())["baselines"]["act"]["args"]
    return {key.removeprefix("policy."): value for key, value in args.items() if key.startswith("policy.")}


class ACT(nn.Module):
    """LeRobot's ACTPolicy as the reference: the benchmark's `act` network and loss (L1 on the chunk + the VAE's KL),
    its own action queue in rollouts. Padding past an episode's end is masked (`action_is_pad`), as LeRobot's
    data loader marks it."""

    name = "act"

    def __init__(self, obs_dim: int, action_dim: int) -> None:
        from lerobot.configs.types import FeatureType, PolicyFeature
        from lerobot.policies.act.configuration_act import ACTConfig
        from lerobot.policies.act.modeling_act import ACTPolicy

        super().__init__()
        self.state_dim = len(STATE_NAMES)
        config = ACTConfig(device="cpu", push_to_hub=False, **act_settings())
        config.input_features = {
            "observation.state": PolicyFeature(FeatureType.STATE, (self.state_dim,)),
            "observation.environment_state": PolicyFeature(FeatureType.ENV, (obs_dim - self.state_dim,)),
        }
        config.output_features = {"action": PolicyFeature(FeatureType.ACTION, (action_dim,))}
        self.policy = ACTPolicy(config)

    def split(self, obs: torch.Tensor) -> dict[str, torch.Tensor]:
        return {
            "observation.state": obs[..., : self.state_dim],
            "observation.environment_state": obs[..., self.state_dim :],
        }

    def examples(self, obs: torch.Tensor, action: torch.Tensor, end: torch.Tensor) -> TensorDict:
        chunk = self.policy.config.chunk_size
        index = ahead(end, chunk)
        is_pad = torch.arange(len(end))[:, None] + torch.arange(chunk)[None, :] >= end[:, None]
        fields = {**self.split(obs), "action": action[index], "action_is_pad": is_pad}
        return TensorDict(fields, batch_size=[len(obs)])

    def loss(self, batch: TensorDict) -> torch.Tensor:
        return self.policy.forward(batch.to_dict())[0]

    def actor(self):
        self.policy.reset()

        def act(x: torch.Tensor) -> np.ndarray:
            return self.policy.select_action(self.split(x[None]))[0].numpy()

        return act


REFERENCES = {model.name: model for model in (MLP, RNN, ACT)}
DESCRIPTIONS = {
    "mlp": f"MLP 3x512, chunk {CHUNK}, execute {EXECUTE}",
    "rnn": f"BC-RNN: LSTM 2x400 over {RNN_HORIZON} steps, hidden state reset every {RNN_HORIZON}",
    "act": "LeRobot ACT, the benchmark's settings (chunk {chunk_size}, execute {n_action_steps}, dim {dim_model})",
}
LABELS = {
    "mlp": "MLP (current observation)",
    "rnn": "BC-RNN (history of 10)",
    "act": "LeRobot ACT (benchmark settings)",
}
DEFAULT_BATCH = {"mlp": 512, "rnn": 100, "act": 128}  # rnn: robomimic's BC-RNN batch
DEFAULT_LR = {"mlp": 1e-3, "rnn": 1e-3, "act": 1e-4}  # act: the benchmark's optimizer_lr
RESULT_FOLDERS = {"mlp": RESULTS, "rnn": RESULTS / "bc_rnn", "act": RESULTS / "act"}


def train(
    model: nn.Module, obs, action, end, max_epochs: int, batch: int, lr: float, max_minutes: float, device: str
) -> tuple[nn.Module, dict]:
    """The reference's loss on mean/std-normalised observations and actions, AdamW with cosine decay over
    `max_epochs`, until the plateau rule (or the wall-time cap, recorded as `stopped_by`) stops it. The statistics are
    the demo frames' and travel with the model (`model.stats`); the model comes back on the CPU for rollouts."""
    stats = {
        "obs_mean": obs.mean(0),
        "obs_std": obs.std(0).clamp_min(1e-3),
        "act_mean": action.mean(0),
        "act_std": action.std(0).clamp_min(1e-3),
    }
    examples = model.examples(
        (obs - stats["obs_mean"]) / stats["obs_std"], (action - stats["act_mean"]) / stats["act_std"], end
    ).to(device)
    model.to(device)
    steps_per_epoch = math.ceil(len(examples) / batch)
    optimizer = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, max_epochs * steps_per_epoch)
    curve: list[float] = []
    start = time.monotonic()
    model.train()
    stopped_by = "max_epochs"
    for epoch in range(max_epochs):
        order, total = torch.randperm(len(examples), device=device), torch.zeros((), device=device)
        for i in range(steps_per_epoch):
            pick = order[i * batch : (i + 1) * batch]
            loss = model.loss(examples[pick])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
            total += loss.detach() * len(pick)  # summed on the device: no sync per step
        curve.append(float(total) / len(examples))
        if epoch >= 2 * PLATEAU_EPOCHS:
            before, now = min(curve[:-PLATEAU_EPOCHS]), min(curve[-PLATEAU_EPOCHS:])
            if now > before * (1 - PLATEAU_GAIN):
                stopped_by = "plateau"
                break
        if time.monotonic() - start > 60 * max_minutes:
            stopped_by = f"wall time ({max_minutes} min)"
            break
        if epoch % 50 == 0:
            print(f"  epoch {epoch:4d}  loss {curve[-1]:.2e}  {time.monotonic() - start:.0f} s", flush=True)
    model.stats = stats  # type: ignore[attr-defined]
    elapsed = round(time.monotonic() - start, 1)
    return model.cpu().eval(), {"epochs": len(curve), "train_s": elapsed, "stopped_by": stopped_by, "loss_curve": curve}


def rollout_seeds(episodes: int) -> list[int]:
    """The env seeds of the calibration's rollouts (see `kitchen.seeds`)."""
    return [CALIBRATION_SEED0 + episode for episode in range(episodes)]


@torch.no_grad()
def rollouts(model: nn.Module, task: str, episodes: int, discrete_gripper: bool = True) -> dict:
    from lerobot_skillret.kitchen.gym_env import KitchenEnv

    env = KitchenEnv(task=task, discrete_gripper=discrete_gripper)
    s = model.stats  # type: ignore[attr-defined]
    per_rollout = []
    seeds = rollout_seeds(episodes)
    for episode, seed in enumerate(seeds):
        obs, _ = env.reset(seed=seed)
        act = model.actor()
        best, chain, steps, done = 0.0, 0, 0, False
        while not done:
            x = torch.from_numpy(np.concatenate([obs["agent_pos"], obs["environment_state"]])).float()
            action = act((x - s["obs_mean"]) / s["obs_std"]) * s["act_std"].numpy() + s["act_mean"].numpy()
            obs, reward, terminated, truncated, info = env.step(action)
            best, chain, steps = max(best, reward), max(chain, info["in_a_row"]), steps + 1
            done = terminated or truncated
        row = {
            "success": bool(info["is_success"]),
            "progress": best,
            "in_a_row": chain,
            "steps": steps,
            "unmet": env.unmet_goals(),
        }
        per_rollout.append(row)
        print(f"  rollout {episode:3d}: {row}", flush=True)
    env.close()
    goals = len(TASKS[task].goals)
    return {
        "rollouts": episodes,
        "eval_seeds": [seeds[0], seeds[-1]],
        "success": float(np.mean([r["success"] for r in per_rollout])),
        "progress": float(np.mean([r["progress"] for r in per_rollout])),
        # CALVIN's report: the share of rollouts that completed at least k sub-goals in a row, k = 1..goals
        "in_a_row_at_least": [float(np.mean([r["in_a_row"] >= k for r in per_rollout])) for k in range(1, goals + 1)],
        "per_rollout": per_rollout,
    }


def demos(task: str, episodes: int, workers: int, data_dir: Path) -> Path:
    root = data_dir / f"demos_{task}_n{episodes}"
    if not (root / "meta" / "info.json").is_file():
        cmd = [str(Path(sys.executable).parent / "skillret-generate"), "demos", "--task", task, "--root", str(root)]
        subprocess.run([*cmd, "--episodes", str(episodes), "--workers", str(workers), "--overwrite"], check=True)
    return root


def run_task(task: str, args: argparse.Namespace) -> dict:
    root = demos(task, args.demos, args.workers, args.data_dir)
    columns = EpisodeColumns.from_dataset(f"local/kitchen_demos_{task}", root)
    stats = demo_statistics(columns, root)
    print(f"{task}: {stats}", flush=True)
    torch.manual_seed(args.seed)
    obs, action, end = frames(columns)
    model = REFERENCES[args.reference](obs.shape[1], action.shape[1])
    model, training = train(
        model, obs, action, end, args.max_epochs, args.batch_size, args.lr, args.max_train_minutes, args.device
    )
    print(
        f"{task}: trained {training['epochs']} epochs in {training['train_s']} s ({training['stopped_by']})", flush=True
    )
    weights = args.data_dir / f"bc_{args.reference}_{task}_seed{args.seed}.pt"  # kept for diagnosing its rollouts
    write_atomic(weights, lambda tmp: torch.save({"model": model.state_dict(), "stats": model.stats}, tmp))
    start = time.monotonic()
    evaluation = rollouts(model, task, args.rollouts, args.discrete_gripper)
    return {
        "task": task,
        "level": TASKS[task].level,
        "demos": stats,
        "reference": DESCRIPTIONS[args.reference].format(**act_settings())
        + f", batch {args.batch_size}, lr {args.lr}, seed {args.seed}",
        "device": args.device,
        **{k: v for k, v in training.items() if k != "loss_curve"},
        "final_loss": training["loss_curve"][-1],
        **curve_points(training["loss_curve"]),
        "eval_s": round(time.monotonic() - start, 1),
        "discrete_gripper": args.discrete_gripper,
        **evaluation,
    }


def curve_points(curve: list[float], points: int = 100) -> dict:
    """About `points` (epoch, loss) samples of a loss curve, its last epoch included: enough to see it flatten."""
    epochs = list(range(0, len(curve), max(1, len(curve) // points)))
    epochs += [len(curve) - 1] if epochs[-1] != len(curve) - 1 else []
    return {"loss_curve_epochs": epochs, "loss_curve": [curve[e] for e in epochs]}


def ran_discrete_gripper(result: dict) -> bool:
    """Whether a stored result's rollouts rounded the gripper command (results from before 2026-12-05 lack the key:
    they sent the continuous one)."""
    return result.get("discrete_gripper", False)


def table(folder: Path) -> str:
    rows = sorted((json.loads(p.read_text()) for p in folder.glob("*.json")), key=lambda r: (r["level"], r["task"]))
    references = sorted({r["reference"].split(", batch")[0] for r in rows})
    lines = [
        f"Reference: {'; '.join(references)}. Epochs marked * stopped at a cap (epochs or wall time), not at the "
        "plateau rule: check its loss curve. Rollouts from env seeds "
        f"{CALIBRATION_SEED0}+ (kitchen.seeds.CALIBRATION_SEED0); rollouts marked † were from another range (the "
        "benchmark's evaluation seeds, before calibration had its own): re-run that task to replace them. Rollouts "
        "marked ‡ sent the continuous gripper command (before 2026-12-05); the others round it to open / hold / "
        "close, the env's default.",
        "",
        "| level | task | BC success | progress | rollouts | epochs | final loss | train min | demo length (median) "
        "| expert | in a row >= 1 / 2 / ... |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        chain = " / ".join(f"{100 * x:.0f}" for x in r.get("in_a_row_at_least", [])) or "-"
        lines.append(
            f"| {r['level']} | {r['task']} | {100 * r['success']:.0f} % | {100 * r['progress']:.0f} % | {r['rollouts']}"
            f"{'' if r['eval_seeds'][0] == CALIBRATION_SEED0 else '†'}{'' if ran_discrete_gripper(r) else '‡'} "
            f"| {r['epochs']}{'' if r.get('stopped_by', 'plateau') == 'plateau' else '*'} | {r['final_loss']:.1e} | {r['train_s'] / 60:.1f} | {r['demos']['length_min_median_max'][1]} "
            f"| {r['demos']['expert_success']} | {chain} |"
        )
    return "\n".join(lines) + "\n"


def plot_curves(folder: Path) -> Path:
    """One log-scale training-loss curve per stored task: each should flatten out before its last epoch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4))
    for path in sorted(folder.glob("*.json")):
        r = json.loads(path.read_text())
        axis.plot(r["loss_curve_epochs"], r["loss_curve"], label=f"{r['task']} (level {r['level']})")
        title = r["reference"].split(", batch")[0]
    axis.set(yscale="log", xlabel="epoch", ylabel="training loss (normalised; MSE, ACT: L1 + KL)", title=title)
    axis.legend(fontsize=7)
    out = folder / "loss_curves.png"
    write_atomic(out, lambda tmp: figure.savefig(tmp, dpi=110, bbox_inches="tight", format="png"))
    plt.close(figure)
    return out


def plot_ladder(folders: dict[str, Path], out: Path) -> Path:
    """Success per task (ladder order) for each reference's results folder, against the calibration goals:
    >= 60 % on single steps, 15-50 % on multi-step tasks (the seed's target-only regime)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    found = {label: {p.stem: json.loads(p.read_text()) for p in f.glob("*.json")} for label, f in folders.items()}
    tasks = sorted({t for rows in found.values() for t in rows}, key=lambda t: (TASKS[t].level, t))
    figure, axis = plt.subplots(figsize=(max(6, 0.9 * len(tasks)), 4))
    width = 0.8 / len(found)
    for i, (label, rows) in enumerate(found.items()):
        if any(r.get("stopped_by", "plateau").startswith("wall time") for r in rows.values()):
            label += ", stopped by a wall-time cap"  # then not converged: its bars are lower bounds
        continuous = sorted(t for t, r in rows.items() if not ran_discrete_gripper(r))
        if continuous:  # rolled out before the rounded gripper command became the env's default
            label += (
                ", continuous gripper"
                if len(continuous) == len(rows)
                else f" ({', '.join(continuous)}: continuous gripper)"
            )
        xs = [j + (i - (len(found) - 1) / 2) * width for j, t in enumerate(tasks) if t in rows]
        axis.bar(xs, [100 * rows[t]["success"] for t in tasks if t in rows], width, label=label)
    axis.axhspan(15, 50, color="grey", alpha=0.15, label="multi-step goal: 15-50 %")
    axis.axhline(60, color="grey", linestyle="--", linewidth=1, label="single-step goal: >= 60 %")
    axis.set_xticks(range(len(tasks)), [f"{t}\n(level {TASKS[t].level})" for t in tasks], fontsize=7, rotation=30)
    axis.set(
        ylabel="success (%), 50 held-out rollouts", ylim=(0, 105), title="BC trained to a plateau on 30 demos per task"
    )
    axis.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    write_atomic(out, lambda tmp: figure.savefig(tmp, dpi=110, bbox_inches="tight", format="png"))
    plt.close(figure)
    return out


def redo_reason(stored: dict, discrete_gripper: bool) -> str | None:
    """Why a stored result does not answer this run (None: it does): rolled out from other env seeds, or with the
    other gripper command (results from before 2026-12-05 lack the key: they ran the continuous one)."""
    first_seed, discrete = stored["eval_seeds"][0], ran_discrete_gripper(stored)
    if first_seed != CALIBRATION_SEED0:
        return f"its result was rolled out from env seeds {first_seed}+, not the calibration's"
    if discrete != discrete_gripper:
        return f"its result ran with discrete_gripper={discrete}, this run with {discrete_gripper}"
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=sorted(TASKS, key=lambda t: (TASKS[t].level, t)))
    parser.add_argument("--demos", type=int, default=30, help="target demonstrations per task")
    parser.add_argument("--rollouts", type=int, default=50, help="rollouts from held-out initial states")
    parser.add_argument(
        "--max-epochs",
        type=int,
        default=2000,
        help="upper bound and the cosine schedule's length (published runs: 800 mlp, 100 rnn)",
    )
    parser.add_argument("--reference", choices=sorted(REFERENCES), default="mlp", help="the BC model (see above)")
    parser.add_argument("--batch-size", type=int, help=f"default: {DEFAULT_BATCH} (rnn: robomimic's)")
    parser.add_argument("--lr", type=float, help=f"AdamW's initial learning rate (cosine decay); default: {DEFAULT_LR}")
    parser.add_argument("--device", default="cpu", help="where the reference trains (rollouts run on the CPU)")
    parser.add_argument("--max-train-minutes", type=float, default=float("inf"), help="wall-time cap on training")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--discrete-gripper",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="roll out with the gripper command rounded to open / hold / close, the env's default "
        "(`--no-discrete-gripper`: the continuous command the published calibration used)",
    )
    parser.add_argument("--workers", type=int, default=1, help="simulation workers of the demo generator")
    parser.add_argument("--data-dir", type=Path, default=ROOT / "outputs" / "learnability")
    parser.add_argument("--results", type=Path, help=f"default: {RESULTS} for mlp, its bc_rnn/ or act/ for the others")
    parser.add_argument("--force", action="store_true", help="redo tasks that already have a result")
    parser.add_argument(
        "--table",
        action="store_true",
        help="no training: rebuild the table and plots from the stored results and exit",
    )
    args = parser.parse_args()
    args.batch_size = args.batch_size or DEFAULT_BATCH[args.reference]
    args.lr = args.lr or DEFAULT_LR[args.reference]
    args.results = args.results or RESULT_FOLDERS[args.reference]
    unknown = [t for t in args.tasks if t not in TASKS]
    if unknown:
        parser.error(f"unknown tasks {unknown}; choose from {sorted(TASKS)}")
    if not args.table:
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        for task in args.tasks:
            out = args.results / f"{task}.json"
            if out.exists() and not args.force:
                reason = redo_reason(json.loads(out.read_text()), args.discrete_gripper)
                if reason is None:
                    print(f"{task}: done already ({out}); --force to redo", flush=True)
                    continue
                print(f"{task}: redone: {reason}", flush=True)
            write_json_atomic(out, run_task(task, args))
    if not any(args.results.glob("*.json")):
        parser.error(f"no stored results in {args.results}: run without --table first (or pass --results)")
    markdown = table(args.results)
    write_text_atomic(args.results / "results.md", markdown)
    print(markdown)
    print(f"loss curves: {plot_curves(args.results)}")
    if args.results.resolve() in RESULT_FOLDERS.values():  # the published results: every reference in one plot
        folders = {LABELS[name]: folder for name, folder in RESULT_FOLDERS.items() if any(folder.glob("*.json"))}
        ladder = RESULTS / "ladder.png"
    else:  # results kept elsewhere never overwrite the published plot
        folders, ladder = {LABELS[args.reference]: args.results}, args.results / "ladder.png"
    print(f"success per task and reference: {plot_ladder(folders, ladder)}")


if __name__ == "__main__":
    main()
