"""The pipeline's configuration file (YAML, see `configs/pipeline/`): what to generate, train, retrieve and evaluate.

Parsed by draccus, as LeRobot's configs are: a YAML file plus `--key.sub=value` overrides. Every training stage is a
stock `lerobot-train` run; its options are written exactly as on the command line (`policy.horizon: 10` becomes
`--policy.horizon=10`), so a config file reads like the commands it runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import draccus
import yaml

from lerobot_skillret.kitchen.generate import (
    DEFAULT_DEMOS,
    DEFAULT_PLAY_EPISODES,
    DEFAULT_PLAY_STEPS,
    DEFAULT_WORKERS,
)
from lerobot_skillret.kitchen.tasks import TASKS
from lerobot_skillret.pipeline.methods import METHODS
from lerobot_skillret.retrieval.cli import as_arguments


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


# Options the pipeline itself gives every stage of a command: where the data, the outputs and the policy come from,
# the seed, and what makes a method that method. Given in a section's `args` as well, one of the two values would be
# dropped silently. (`policy.prior_root: null` stays allowed: with `policy.prior_repo_id: null` it is how a config
# trains a prior-skill variant without its prior windows.)
PIPELINE_OPTIONS = {
    "lerobot-train": (
        "dataset.repo_id",
        "dataset.root",
        "output_dir",
        "job_name",
        "seed",
        "policy.type",
        "policy.path",
        "policy.stage",
        "policy.use_retrieval",
        "policy.retrieval_path",
    ),
    "lerobot-eval": ("policy.path", "env.type", "env.task", "seed", "output_dir"),
    "skillret-retrieve": (
        "checkpoint",
        "prior-root",
        "prior-repo-id",
        "target-root",
        "target-repo-id",
        "output",
        "report-dir",
        "seed",
    ),
}
# Options that a section's own field sets (`skills.steps: 1000` is `--steps=1000`): the field is what the pipeline
# reads back (which checkpoints exist, how many rollouts), so it must be the only place the value is given.
SECTION_FIELDS = {
    "lerobot-train": {name: name for name in ("steps", "batch_size", "save_freq", "num_workers", "config_path")},
    "lerobot-eval": {
        "eval.n_episodes": "n_episodes",
        "eval.batch_size": "batch_size",
        "env.episode_length": "episode_length",
    },
}


def _check_owned_options(where: str, options: dict[str, Any], command: str) -> None:
    """Refuse an `args` key that the pipeline or the section's own field already sets (see PIPELINE_OPTIONS)."""
    section = where.removesuffix(".args")
    for key in options:
        flag = key.replace("_", "-") if command == "skillret-retrieve" else key
        if flag in PIPELINE_OPTIONS[command]:
            raise ValueError(
                f"pipeline config: `{where}` key `{key}` is set by the pipeline for every {command} it runs "
                "(data, outputs, seeds and each method's wiring); remove it."
            )
        if key in SECTION_FIELDS.get(command, {}):
            raise ValueError(
                f"pipeline config: `{where}` key `{key}` repeats `{section}.{SECTION_FIELDS[command][key]}`, which "
                "the pipeline reads back: set that field instead."
            )


def _policy_values(spec: TrainSpec, with_file: bool = True) -> dict[str, Any]:
    """The policy settings a training section gives: its config file's `policy` section (`with_file`: a run from a
    checkpoint, --policy.path, takes the checkpoint's instead), then its `policy.*` args."""
    values: dict[str, Any] = {}
    if with_file and spec.config_path is not None and Path(spec.config_path).is_file():  # a missing one: refused
        try:  # lerobot-train reads JSON or YAML config files; YAML reads both
            values = dict(yaml.safe_load(Path(spec.config_path).read_text()).get("policy") or {})
        except (yaml.YAMLError, AttributeError, TypeError, ValueError) as err:
            raise ValueError(f"pipeline config: {spec.config_path} is no lerobot-train config file: {err}") from None
    for key, value in spec.args.items():
        if key.startswith("policy."):
            *parents, name = key.removeprefix("policy.").split(".")
            node = values
            for parent in parents:  # `policy.optimizer.lr: 0.1` -> {"optimizer": {"lr": 0.1}}
                node = node.setdefault(parent, {})
            node[name] = value
    return values


def _check_policy_values(where: str, values: dict[str, Any], policy_type: str, note: str = "") -> None:
    """Build the `policy_type` config from `values` over its defaults, so that a value the config's own checks refuse
    (`policy.horizon: 0`, ACT's n_action_steps > chunk_size) is refused before any stage runs, not when its stage
    starts."""
    values = {k: v for k, v in values.items() if k not in ("type", "path")}
    if not values:
        return
    (config_class,) = _policy_configs([policy_type])
    try:  # a device given, so that LeRobot does not log its device auto-selection for a config only checked here
        draccus.decode(config_class, {"device": "cpu", **values})
    except (draccus.utils.ParsingError, NotImplementedError) as err:  # ACT: NotImplementedError for some settings
        # a value of the wrong type (DecodingError) names itself; a value the config's own check refused is the cause
        reason = err if isinstance(err, draccus.utils.DecodingError) else err.__cause__ or err
        raise ValueError(f"pipeline config: `{where}`{note} gives {policy_type} a value it refuses: {reason}") from None


def _check_option_keys(where: str, options: dict[str, Any], command: str, policy_types: Sequence[str]) -> None:
    """Refuse an `args` key that `command` has no option for, before any stage runs (the command itself would only
    refuse it when its stage starts, after the data and stage 1): its first part must be a field of the command's
    config, and its second a field of that section (`dataset`, the kitchen `env`, or the config of every policy
    type in `policy_types` the options reach)."""
    if not options:
        return
    from lerobot.configs.default import DatasetConfig
    from lerobot.configs.eval import EvalPipelineConfig
    from lerobot.configs.train import TrainPipelineConfig

    from lerobot_skillret.kitchen.env_config import PandaKitchenEnv

    def names(config_class: type) -> set[str]:
        return {f.name for f in fields(config_class)}

    command_fields = names(TrainPipelineConfig if command == "lerobot-train" else EvalPipelineConfig)
    sections = {  # built on demand: the policy configs import every LeRobot policy type
        "dataset": lambda: [DatasetConfig],
        "env": lambda: [PandaKitchenEnv],
        "policy": lambda: _policy_configs(policy_types),
    }
    for key in options:
        head, _, rest = key.partition(".")
        if head not in command_fields:
            raise ValueError(f"pipeline config: `{where}` key `{key}` is no {command} option (see {command} --help).")
        option = rest.split(".")[0]
        if option and head in sections and any(option not in names(c) | {"type", "path"} for c in sections[head]()):
            reach = f" for policy type(s) {list(policy_types)}" if head == "policy" else ""
            raise ValueError(
                f"pipeline config: `{where}` key `{key}`: `{head}` has no option `{option}`{reach} (see {command} --help)."
            )


def _policy_configs(policy_types: Sequence[str]) -> list[type]:
    import lerobot.policies  # noqa: F401  (registers LeRobot's policy types)
    from lerobot.configs.policies import PreTrainedConfig

    import lerobot_skillret.policy  # noqa: F401  (registers skillret)

    return [PreTrainedConfig.get_choice_class(policy_type) for policy_type in policy_types]


@dataclass
class DataSpec:
    """Kitchen data generated once per output folder and shared by every method."""

    play_episodes: int = DEFAULT_PLAY_EPISODES  # prior play trajectories (the seed's real-kitchen prior: 150 x ~2,000)
    play_steps: int = DEFAULT_PLAY_STEPS  # steps per play trajectory
    demo_episodes: int = DEFAULT_DEMOS  # successful target demonstrations per task
    workers: int = DEFAULT_WORKERS  # generator worker processes
    seed: int = 0  # generation seed (datasets are reproducible from it)
    cameras: bool = False  # camera datasets: not supported by the pipeline yet (rejected with the reason)


@dataclass
class TrainSpec:
    """One `lerobot-train` run: its length, checkpoints and extra command-line options."""

    config_path: str | None = None  # a full lerobot-train config file (e.g. configs/policy/cpu.json)
    steps: int = 1000
    batch_size: int = 16
    save_freq: int = 500  # checkpoints evaluated by the protocol are every `save_freq` steps and the last one
    num_workers: int = 0  # dataloader workers (0 keeps 2-core machines responsive)
    args: dict[str, Any] = field(default_factory=dict)  # e.g. {"policy.encoder_lstm_hidden": 256}


@dataclass
class BaselineSpecs:
    """LeRobot's own policies as the seed's baselines (C.4): one `lerobot-train` spec per section, absent (None) when
    no method of the config needs it. Named fields rather than a dict, so that draccus takes command-line overrides
    such as `--baselines.act.steps=16000` as for any other key."""

    act: TrainSpec | None = None  # ACT on the target demos
    diffusion: TrainSpec | None = None  # Diffusion Policy on the target demos
    act_ft_prior: TrainSpec | None = None  # ACT pre-trained on the play data, once per seed (shared by the tasks)
    act_ft: TrainSpec | None = None  # that ACT fine-tuned on the target demos

    def __getitem__(self, name: str) -> TrainSpec:
        if name not in self:
            raise KeyError(f"pipeline config has no `baselines.{name}` section (its lerobot-train options).")
        return getattr(self, name)

    def __contains__(self, name: str) -> bool:
        return name in self.names() and getattr(self, name) is not None

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    def items(self) -> list[tuple[str, TrainSpec]]:
        """The sections the config gives, by name."""
        return [(name, getattr(self, name)) for name in self.names() if name in self]


@dataclass
class RetrievalSpec:
    """`skillret-retrieve` options shared by the retrieval-based methods (values as on its command line)."""

    args: dict[str, Any] = field(default_factory=dict)  # e.g. {"fraction": 0.1, "metric": "l2"}


@dataclass
class EvalSpec:
    """The seed's protocol (C.3): N rollouts per evaluated checkpoint, best checkpoint per seed."""

    n_episodes: int = 100  # rollouts per checkpoint
    batch_size: int = 10  # parallel (synchronous) envs per lerobot-eval run; <= n_episodes
    max_checkpoints: int = 5  # evaluate at most this many checkpoints per run (the latest ones)
    episode_length: int | None = None  # override the task's rollout length (None = the task's own)
    args: dict[str, Any] = field(default_factory=dict)  # extra lerobot-eval options


@dataclass
class HeldoutSpec:
    """Demonstrations no run trains on (another generation seed), for `skillret-pipeline heldout`'s offline score."""

    episodes: int = 10  # successful demonstrations per task
    seed: int = 7  # generation seed; must differ from `data.seed`, or the "held-out" demos are the training ones


@dataclass
class PipelineConfig:
    output_dir: str = "outputs/pipeline"
    tasks: list[str] = field(default_factory=lambda: ["cleaning_up"])
    seeds: list[int] = field(default_factory=lambda: [0])
    methods: list[str] = field(default_factory=lambda: ["skillret"])  # names in `methods.METHODS`
    results_dir: str | None = None  # finished cells' eval JSONs, cell.json, retrieval_summary.json go here
    threads: int | None = None  # OMP_NUM_THREADS of every stage (1 avoids oversubscription on a shared machine)
    jobs: int = 1  # cells run at once (one core each with threads: 1); shared stages are built once, under a lock
    data: DataSpec = field(default_factory=DataSpec)
    skills: TrainSpec = field(default_factory=TrainSpec)  # stage 1 (shared by tasks; one per seed)
    policy: TrainSpec = field(default_factory=TrainSpec)  # stage 2 (one per method, task and seed)
    retrieval: RetrievalSpec = field(default_factory=RetrievalSpec)
    baselines: BaselineSpecs = field(default_factory=BaselineSpecs)
    eval: EvalSpec = field(default_factory=EvalSpec)
    heldout: HeldoutSpec = field(default_factory=HeldoutSpec)

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise ValueError(f"pipeline config: unknown methods {unknown}; choose from {list(METHODS)}.")
        for method in self.methods:
            for key in METHODS[method].baselines:
                if key not in self.baselines:
                    raise ValueError(
                        f"pipeline config: method `{method}` needs a `baselines.{key}` section "
                        "(its lerobot-train options)."
                    )
        unknown_tasks = [t for t in self.tasks if t not in TASKS]
        if unknown_tasks:
            raise ValueError(f"pipeline config: unknown tasks {unknown_tasks}; choose from {sorted(TASKS)}.")
        if self.data.cameras:
            raise ValueError(
                "pipeline config: `data.cameras: true` is not supported by the pipeline yet (retrieval and the "
                "cpu policy config read low-dim windows only); train camera policies with lerobot-train directly."
            )
        if not isinstance(self.jobs, int) or isinstance(self.jobs, bool) or self.jobs < 1:
            raise ValueError(f"pipeline config: `jobs` must be >= 1 (got {self.jobs}); use the number of cores.")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"pipeline config: `threads` must be >= 1 or null (got {self.threads}).")
        for name in ("play_episodes", "play_steps", "demo_episodes"):
            if getattr(self.data, name) < 1:
                raise ValueError(f"pipeline config: `data.{name}` must be >= 1 (got {getattr(self.data, name)}).")
        if self.data.workers < 0:
            raise ValueError(f"pipeline config: `data.workers` must be >= 0 (got {self.data.workers}; 0: in-process).")
        if not self.tasks or not self.seeds or not self.methods:
            raise ValueError("pipeline config: `tasks`, `seeds` and `methods` must each name at least one entry.")
        counts = {f"eval.{name}": getattr(self.eval, name) for name in ("n_episodes", "batch_size", "max_checkpoints")}
        for name, value in (counts | {"heldout.episodes": self.heldout.episodes}).items():
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"pipeline config: `{name}` must be an integer >= 1 (got {value!r}).")
        if self.eval.batch_size > self.eval.n_episodes:
            raise ValueError(
                f"pipeline config: `eval.batch_size`={self.eval.batch_size} exceeds `eval.n_episodes`="
                f"{self.eval.n_episodes}; lerobot-eval needs batch_size <= n_episodes."
            )
        if self.heldout.seed == self.data.seed:
            raise ValueError(
                f"pipeline config: `heldout.seed` equals `data.seed`={self.data.seed}: those demos are the training "
                "ones, not held out; pick another generation seed."
            )
        specs = {"skills": self.skills, "policy": self.policy} | {
            f"baselines.{k}": v for k, v in self.baselines.items()
        }
        policy_types = {"skills": "skillret", "policy": "skillret"} | {  # act_ft_prior trains act_ft's policy
            f"baselines.{k}": METHODS[k.removesuffix("_prior")].lerobot_type for k, _ in self.baselines.items()
        }
        for name in ("output_dir", "results_dir"):
            if getattr(self, name) is not None and Path(getattr(self, name)).is_file():
                raise ValueError(f"pipeline config: `{name}` {getattr(self, name)} is a file; pass a folder path.")
        seeds = [*self.seeds, self.data.seed, self.heldout.seed]
        if any(not isinstance(seed, int) or seed < 0 for seed in seeds):
            raise ValueError(
                f"pipeline config: seeds must be integers >= 0 (`seeds`, `data.seed`, `heldout.seed`: {seeds})."
            )
        if self.eval.episode_length is not None and self.eval.episode_length < 1:
            raise ValueError(
                "pipeline config: `eval.episode_length` must be >= 1, or null for the task's own "
                f"(got {self.eval.episode_length})."
            )
        _check_owned_options("retrieval.args", self.retrieval.args, "skillret-retrieve")
        _check_owned_options("eval.args", self.eval.args, "lerobot-eval")
        try:
            as_arguments(self.retrieval.args)
        except ValueError as err:
            raise ValueError(f"pipeline config: `retrieval.args`: {err}") from None
        evaluated = {METHODS[m].lerobot_type or "skillret" for m in self.methods}  # eval.args reach every method
        _check_option_keys("eval.args", self.eval.args, "lerobot-eval", sorted(evaluated))
        for spec_name, spec in specs.items():
            if spec.steps < 1 or spec.save_freq < 1 or spec.batch_size < 1 or spec.num_workers < 0:
                raise ValueError(
                    f"pipeline config: `{spec_name}` needs steps, save_freq and batch_size >= 1, num_workers >= 0."
                )
            _check_option_keys(f"{spec_name}.args", spec.args, "lerobot-train", [policy_types[spec_name]])
            _check_owned_options(f"{spec_name}.args", spec.args, "lerobot-train")
            if spec.config_path is not None and not Path(spec.config_path).is_file():
                raise FileNotFoundError(
                    f"pipeline config: `{spec_name}.config_path` {spec.config_path} not found (relative paths are "
                    f"read from the current folder {Path.cwd()}); run from the repository root or give an "
                    "absolute path."
                )
        starts_from = {"policy": "skills", "baselines.act_ft": "baselines.act_ft_prior"}  # its checkpoint's run
        for spec_name, spec in specs.items():
            base = specs.get(starts_from.get(spec_name, ""))  # then the spec's own file is not read (--policy.path)
            values = _policy_values(spec) if base is None else _policy_values(base) | _policy_values(spec, False)
            variants = {"": {}}  # the skillret variants add their own options to stage 2 (`Method.policy_args`)
            if spec_name == "policy":
                variants |= {
                    f" with {m}'s own options": METHODS[m].policy_args for m in self.methods if METHODS[m].policy_args
                }
            for label, own in variants.items():
                own_values = {key.removeprefix("policy."): value for key, value in own.items()}
                _check_policy_values(spec_name, values | own_values, policy_types[spec_name], label)

    @classmethod
    def from_args(cls, config_path: str | Path, args: Sequence[str] = ()) -> PipelineConfig:
        """The YAML file, then command-line overrides written as for lerobot-train (draccus): `--eval.n_episodes=10`,
        `--tasks=[cook,breakfast]`, `--policy.args={policy.horizon: 5}`. Unknown keys and values of the wrong type
        are refused with the key named."""
        path = Path(config_path)
        if not path.is_file():
            raise FileNotFoundError(f"pipeline config {path} not found (see configs/pipeline/ for examples).")
        try:
            content = yaml.safe_load(path.read_text())
        except yaml.YAMLError as err:
            raise ValueError(f"{path}: {err}") from None
        if not isinstance(content, dict):  # draccus fails on these with an AttributeError
            raise ValueError(
                f"{path} holds {type(content).__name__}, not a mapping of settings: write `key: value` lines, as in "
                "configs/pipeline/benchmark.yaml."
            )
        try:
            return draccus.parse(cls, config_path=path, args=list(args))
        except draccus.utils.DecodingError as err:
            raise ValueError(f"{path}: {err}. Correct it in the config file or the command-line override.") from None
        except draccus.utils.ParsingError as err:  # wraps what __post_init__ refused
            cause = err.__cause__
            if isinstance(cause, (ValueError, FileNotFoundError)):
                raise cause from None
            raise ValueError(f"{path}: {cause or err}") from None
