"""The pipeline's stage graph: which commands produce which artifacts, per method, task and seed.

Layout of the output folder (every path is an artifact; a stage is skipped when its artifact exists):

    data/play, data/demos_<task>                        LeRobotDatasets (skillret-generate)
    skills/prior_seed<s>, skills/target_<task>_seed<s>  stage-1 runs (lerobot-train, stage=skills)
    retrieval/<task>_<mode>_seed<s>/                    retrieval.safetensors + report/ (skillret-retrieve)
    train/<method>/<task>/seed<s>                       stage-2 / baseline runs (lerobot-train)
    eval/<method>/<task>/seed<s>/step<k>                lerobot-eval outputs (eval_info.json, videos/)
    heldout/seed<g>_n<n>/demos_<task>                   held-out demos (generation seed g, n episodes)
    heldout/seed<g>_n<n>/<method>/<task>/seed<s>.json   their imitation errors (skillret-pipeline heldout)
    cells/<method>/<task>/seed<s>.json                  the protocol's summary of one (method, task, seed) cell
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lerobot_skillret.kitchen.fingerprint import kitchen_fingerprint
from lerobot_skillret.pipeline.config import PipelineConfig, TrainSpec
from lerobot_skillret.pipeline.methods import METHODS
from lerobot_skillret.pipeline.stages import Stage

BIN = Path(sys.executable).parent
PRETRAINED = Path("checkpoints/last/pretrained_model")


def cli_args(options: dict[str, Any]) -> list[str]:
    """{"policy.horizon": 10} -> ["--policy.horizon=10"] (None -> null, booleans lower-case, lists as JSON)."""
    out = []
    for key, value in options.items():
        if value is None:
            text = "null"
        elif isinstance(value, bool):
            text = str(value).lower()
        elif isinstance(value, list | tuple):
            text = "[" + ",".join(str(v) for v in value) + "]"
        else:
            text = str(value)
        out.append(f"--{key}={text}")
    return out


@dataclass(frozen=True)
class Cell:
    """One entry of the results table before seed aggregation."""

    method: str
    task: str
    seed: int


class Plan:
    """Builds the stages of a pipeline config; pure path and command arithmetic, no side effects."""

    def __init__(self, cfg: PipelineConfig) -> None:
        self.cfg = cfg
        self.root = Path(cfg.output_dir).resolve()

    # --- data ---------------------------------------------------------------------------------------------
    def play_root(self) -> Path:
        return self.root / "data" / "play"

    def demos_root(self, task: str) -> Path:
        return self.root / "data" / f"demos_{task}"

    @staticmethod
    def repo_id(root: Path) -> str:
        return f"local/kitchen_{root.name}"

    def data_stages(self) -> list[Stage]:
        d = self.cfg.data
        play = Stage("data/play", self.play_root())
        play.command = [
            str(BIN / "skillret-generate"),
            "play",
            "--root",
            str(play.partial),
            "--repo-id",
            self.repo_id(play.output),
            "--episodes",
            str(d.play_episodes),
            "--steps-per-episode",
            str(d.play_steps),
            *self._generation_args(d.seed),
        ]
        play.tags = (f"kitchen={kitchen_fingerprint()}",)
        stages = [play] if self.needs_prior() else []
        for task in self.cfg.tasks:
            stages.append(self._demos_stage(f"data/demos_{task}", self.demos_root(task), task, d.demo_episodes, d.seed))
        return stages

    def _generation_args(self, seed: int) -> list[str]:
        return ["--seed", str(seed), "--workers", str(self.cfg.data.workers)]  # low-dim only (no cameras)

    def _demos_stage(self, name: str, root: Path, task: str, episodes: int, seed: int) -> Stage:
        stage = Stage(name, root)
        stage.command = [
            str(BIN / "skillret-generate"),
            "demos",
            "--task",
            task,
            "--root",
            str(stage.partial),
            "--repo-id",
            self.repo_id(stage.output),
            "--episodes",
            str(episodes),
            *self._generation_args(seed),
        ]
        stage.tags = (f"kitchen={kitchen_fingerprint()}",)  # demos of an older kitchen are not reused
        return stage

    def needs_prior(self) -> bool:
        """Play data is generated only if a method reads it: skills from the prior, or ACT's pre-training."""
        return any(METHODS[m].reads_prior for m in self.cfg.methods)

    # --- training -----------------------------------------------------------------------------------------
    def _train(self, name: str, output: Path, dataset_root: Path, spec: TrainSpec, seed: int, head: list[str]) -> Stage:
        stage = Stage(name, output)
        stage.command = [
            str(BIN / "lerobot-train"),
            *head,
            f"--dataset.repo_id={self.repo_id(dataset_root)}",
            f"--dataset.root={dataset_root}",
            f"--output_dir={stage.partial}",
            f"--job_name={name.replace('/', '_')}",
            f"--steps={spec.steps}",
            f"--batch_size={spec.batch_size}",
            f"--save_freq={spec.save_freq}",
            f"--num_workers={spec.num_workers}",
            f"--seed={seed}",
            "--env_eval_freq=0",
            "--wandb.enable=false",
            "--policy.push_to_hub=false",
            *([f"--config_path={Path(spec.config_path).resolve()}"] if spec.config_path else []),
            *cli_args(spec.args),
        ]
        return stage

    def skills_dir(self, seed: int, task: str | None = None) -> Path:
        """Stage-1 run on the prior (shared by tasks), or on one task's demos (the "no prior data" ablation)."""
        name = f"prior_seed{seed}" if task is None else f"target_{task}_seed{seed}"
        return self.root / "skills" / name

    def skills_stage(self, seed: int, task: str | None = None) -> Stage:
        out = self.skills_dir(seed, task)
        data = self.play_root() if task is None else self.demos_root(task)
        head = ["--policy.type=skillret", "--policy.stage=skills"]
        return self._train(f"skills/{out.name}", out, data, self.cfg.skills, seed, head)

    def retrieval_dir(self, task: str, method: str, seed: int) -> Path:
        """One folder per retrieval: the file stage 2 reads and its report, published together."""
        return self.root / "retrieval" / f"{task}_{method}_seed{seed}"

    def retrieval_path(self, task: str, method: str, seed: int) -> Path:
        return self.retrieval_dir(task, method, seed) / "retrieval.safetensors"

    def retrieval_summary(self, cell: Cell) -> Path | None:
        """The report summary (precision per primitive, distances) of the retrieval a cell trained on, if any."""
        if METHODS[cell.method].retrieval is None:
            return None
        return self.retrieval_dir(cell.task, cell.method, cell.seed) / "report" / "summary.json"

    def retrieval_stage(self, task: str, method: str, seed: int) -> Stage:
        out = self.retrieval_dir(task, method, seed)
        stage = Stage(f"retrieval/{out.name}", out)
        own = METHODS[method].retrieval or {}
        options = {**self.cfg.retrieval.args, **own, "seed": seed}
        if own.get("ablation") == "all":  # the whole prior is retrieved: a fraction or candidate count contradicts it
            options = {k: v for k, v in options.items() if k.replace("_", "-") not in ("fraction", "num-prior")}
        stage.command = [
            str(BIN / "skillret-retrieve"),
            "--checkpoint",
            str(self.skills_dir(seed) / PRETRAINED),
            "--prior-repo-id",
            self.repo_id(self.play_root()),
            "--prior-root",
            str(self.play_root()),
            "--target-repo-id",
            self.repo_id(self.demos_root(task)),
            "--target-root",
            str(self.demos_root(task)),
            "--output",
            str(stage.partial / "retrieval.safetensors"),
            "--report-dir",
            str(stage.partial / "report"),
            *_retrieve_args(options),
        ]
        return stage

    def train_dir(self, cell: Cell) -> Path:
        return self.root / "train" / cell.method / cell.task / f"seed{cell.seed}"

    def prior_pretraining_dir(self, method: str, seed: int) -> Path:
        return self.root / "train" / f"{method}_prior" / f"seed{seed}"

    def prior_pretraining_stage(self, method: str, seed: int) -> Stage:
        """A LeRobot baseline's pre-training on the prior (`baselines.<method>_prior`), shared by the tasks."""
        out, m = self.prior_pretraining_dir(method, seed), METHODS[method]
        spec, head = self.cfg.baselines[f"{method}_prior"], [f"--policy.type={m.lerobot_type}"]
        return self._train(f"train/{method}_prior/seed{seed}", out, self.play_root(), spec, seed, head)

    def train_stage(self, cell: Cell) -> Stage:
        """Stage 2 of a skillret method, or a LeRobot baseline's training on the target demos."""
        m, seed = METHODS[cell.method], cell.seed
        out, name, target = (
            self.train_dir(cell),
            f"train/{cell.method}/{cell.task}/seed{seed}",
            self.demos_root(cell.task),
        )
        if m.lerobot_type is not None:
            if m.pretrain_on_prior:
                head = [f"--policy.path={self.prior_pretraining_dir(cell.method, seed) / PRETRAINED}"]
            else:
                head = [f"--policy.type={m.lerobot_type}"]
            return self._train(name, out, target, self.cfg.baselines[cell.method], seed, head)
        if m.skills == "target":
            head = [
                f"--policy.path={self.skills_dir(seed, cell.task) / PRETRAINED}",
                "--policy.stage=policy",
                "--policy.use_retrieval=false",
                "--policy.prior_repo_id=null",
                "--policy.prior_root=null",
            ]
        else:
            head = [
                f"--policy.path={self.skills_dir(seed) / PRETRAINED}",
                "--policy.stage=policy",
                f"--policy.prior_repo_id={self.repo_id(self.play_root())}",
                f"--policy.prior_root={self.play_root()}",
            ]
            if m.retrieval is None:
                head.append("--policy.use_retrieval=false")
            else:
                head += [
                    "--policy.use_retrieval=true",
                    f"--policy.retrieval_path={self.retrieval_path(cell.task, cell.method, seed)}",
                ]
        return self._train(name, out, target, self.cfg.policy, seed, head)

    # --- evaluation ---------------------------------------------------------------------------------------
    def checkpoints(self, cell: Cell) -> list[tuple[int, Path]]:
        """The run's saved checkpoints as (step, pretrained_model dir), latest `max_checkpoints` of them."""
        if not (self.train_dir(cell) / "checkpoints").is_dir():
            return []
        ckpts = sorted(
            (int(p.name), p / "pretrained_model")
            for p in (self.train_dir(cell) / "checkpoints").iterdir()
            if p.name.isdigit() and (p / "pretrained_model").is_dir()
        )
        return ckpts[-self.cfg.eval.max_checkpoints :]

    def eval_dir(self, cell: Cell, step: int) -> Path:
        return self.root / "eval" / cell.method / cell.task / f"seed{cell.seed}" / f"step{step}"

    def eval_stage(self, cell: Cell, step: int, checkpoint: Path) -> Stage:
        out = self.eval_dir(cell, step)
        stage = Stage(f"eval/{cell.method}/{cell.task}/seed{cell.seed}/step{step}", out)
        e = self.cfg.eval
        options: dict[str, Any] = {
            "policy.path": checkpoint,
            "env.type": "panda_kitchen",
            "env.task": cell.task,
            "eval.n_episodes": e.n_episodes,
            "eval.batch_size": e.batch_size,
            "eval.use_async_envs": False,
            "seed": 100_000 + cell.seed,
            "output_dir": stage.partial,
            **e.args,
        }
        if e.episode_length is not None:
            options["env.episode_length"] = e.episode_length
        stage.command = [str(BIN / "lerobot-eval"), *cli_args(options)]
        stage.after = lambda partial: _repoint(partial / "eval_info.json", partial, out)
        return stage

    def heldout_dir(self) -> Path:
        """One folder per held-out set, so changing `heldout:` never mixes demos or scores of two sets."""
        h = self.cfg.heldout
        return self.root / "heldout" / f"seed{h.seed}_n{h.episodes}"

    def heldout_root(self, task: str) -> Path:
        return self.heldout_dir() / f"demos_{task}"

    def heldout_stage(self, task: str) -> Stage:
        """Demonstrations of `task` from another generation seed than the training ones (never trained on)."""
        h, root = self.cfg.heldout, self.heldout_root(task)
        return self._demos_stage(str(root.relative_to(self.root)), root, task, h.episodes, h.seed)

    def heldout_path(self, cell: Cell) -> Path:
        return self.heldout_dir() / cell.method / cell.task / f"seed{cell.seed}.json"

    def heldout_scores(self) -> str:
        """Glob pattern, relative to `root`, of every `heldout_path` of this held-out set."""
        return str((self.heldout_dir() / "*" / "*" / "seed*.json").relative_to(self.root))

    @staticmethod
    def published_dir(results_dir: Path, cell: Cell) -> Path:
        """Where a finished cell's raw eval JSONs and summary are kept in the repository."""
        return results_dir / cell.method / cell.task / f"seed{cell.seed}"

    CELL_SUMMARIES = "cells/*/*/seed*.json"  # every `cell_path` below `root`

    def cell_path(self, cell: Cell) -> Path:
        return self.root / "cells" / cell.method / cell.task / f"seed{cell.seed}.json"

    def cells(self) -> list[Cell]:
        return [Cell(m, t, s) for s in self.cfg.seeds for t in self.cfg.tasks for m in self.cfg.methods]


def _retrieve_args(options: dict[str, Any]) -> list[str]:
    """{"num_prior": 1000, "exact": False} -> ["--num-prior=1000", "--no-exact"] (skillret-retrieve's argparse flags)."""
    out = []
    for key, value in options.items():
        flag = key.replace("_", "-")
        out.append((f"--{flag}" if value else f"--no-{flag}") if isinstance(value, bool) else f"--{flag}={value}")
    return out


def _repoint(path: Path, old: Path, new: Path) -> None:
    """lerobot-eval records its video paths under the partial folder; point them at the published one."""
    path.write_text(path.read_text().replace(str(old), str(new)))
