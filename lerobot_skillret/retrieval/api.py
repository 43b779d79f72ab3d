"""`retrieve`: stage-1 checkpoint + prior and target datasets -> retrieval file (Algorithm 2, lines 1-7).

`retrieve` reads top to bottom, and the functions below it come in the order it calls them:
1. Load the skill model (`SkillRetPolicy.from_pretrained`; it carries the stage-1 normalisation statistics).
2. Draw N candidate anchors in the prior (uniform over frames, without replacement; every frame when N is "all"
   or exceeds the prior) and M anchors in the target, and encode their H-step windows with the encoder MEAN
   (`WindowSampler.gather` + `SkillRetPolicy.encode_skill`, batched, no autograd).
3. `select_windows` (on latents; the benchmarks and exactness tests call it directly) scores every candidate by
   its distance to the nearest target latent (`kernels.NearestTarget`, chunked, bounded memory) and keeps the
   K = round(r * N) closest (`kernels.smallest`, float64-exact at the cut), or K random ones, all, or none (A.4).
4. Write a `RetrievalResult` with the fingerprints of the checkpoint and both datasets, and optionally a report.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor
from tqdm.auto import tqdm

from lerobot_skillret.data.fingerprint import checkpoint_fingerprint, dataset_fingerprint
from lerobot_skillret.data.labels import PRIMITIVE_KEY, load_label_names
from lerobot_skillret.data.retrieval_file import RetrievalResult
from lerobot_skillret.files import PRETRAINED, check_creatable, check_replaceable_dir, read_json, staged_dir
from lerobot_skillret.retrieval.kernels import NearestTarget, Selection, smallest
from lerobot_skillret.retrieval.report import ReportInputs, label_names, relevant_labels, write_report
from lerobot_skillret.retrieval.settings import EVERY_WINDOW, RetrievalSettings

if TYPE_CHECKING:
    from lerobot_skillret.data.windows import EpisodeColumns
    from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

log = logging.getLogger(__name__)

# Offsets of the seed for independent random streams (candidate anchors, target anchors, random mode).
STREAM_CANDIDATES, STREAM_TARGETS, STREAM_RANDOM = 0, 1, 2


def generator(seed: int, stream: int) -> torch.Generator:
    """A generator per purpose, so changing e.g. the mode does not change which anchors are candidates."""
    return torch.Generator().manual_seed(seed * 7919 + stream)


@dataclass
class Encoded:
    """Encoder outputs of a list of windows, in the order of their anchors."""

    mean: Tensor  # [n, D] float32
    log_var: Tensor | None  # [n, D] float32, kept only for the KL metric


def retrieve(
    checkpoint: str | Path,
    prior_repo_id: str,
    prior_root: str | Path,
    target_repo_id: str,
    target_root: str | Path,
    output: str | Path | None = None,
    settings: RetrievalSettings | None = None,
    *,
    report_dir: str | Path | None = None,
    relevant_primitives: list[str] | None = None,
    device: str | None = None,
    progress: bool = True,
) -> RetrievalResult:
    """Retrieve prior windows for the target task and (with `output`) write the retrieval file atomically.

    Unset `settings` values come from the checkpoint's config; the resolved ones are stored in the file.
    `report_dir` also writes the JSON summary and plots (`report.write_report`).
    """
    from lerobot_skillret.data.windows import EpisodeColumns

    if output is not None and Path(output).is_dir():
        raise ValueError(
            f"--output {output} is a folder: pass the retrieval file's path (e.g. {output}/retrieval.safetensors)"
        )
    if output is not None:
        check_creatable(Path(output), "--output")
    if report_dir is not None:
        check_creatable(Path(report_dir), "--report-dir")
        check_replaceable_dir(Path(report_dir), "summary.json", "pass a new or empty folder (e.g. <output>_report)")
    pretrained = resolve_checkpoint(checkpoint)
    policy = load_skill_model(pretrained, device)
    settings = (settings or RetrievalSettings()).resolve(policy.config)
    info: dict[str, Any] = {
        **settings.to_dict(),
        "checkpoint": str(pretrained),
        "prior_repo_id": prior_repo_id,
        "target_repo_id": target_repo_id,
        "horizon": policy.config.horizon,
        "latent_dim": policy.config.latent_dim,
    }
    if settings.mode == "none":  # the "no retrieval" ablation: nothing to encode, so the datasets are only hashed
        fingerprints = _fingerprints(pretrained, dataset_fingerprint(prior_root), dataset_fingerprint(target_root))
        dim = policy.config.latent_dim
        result = RetrievalResult(
            torch.empty(0, dtype=torch.int64), torch.empty(0), torch.empty(0, dim), info, **fingerprints
        )
        return _finish(result, output, report_dir, None)

    prior_columns = EpisodeColumns.from_dataset(prior_repo_id, prior_root)
    target_columns = EpisodeColumns.from_dataset(target_repo_id, target_root)
    policy.warn_outside_skills_range(target_columns, Path(target_root))
    fingerprints = _fingerprints(pretrained, prior_columns.fingerprint, target_columns.fingerprint)
    candidates = choose_anchors(len(prior_columns), settings.num_prior, generator(settings.seed, STREAM_CANDIDATES))
    targets = choose_anchors(len(target_columns), settings.num_target, generator(settings.seed, STREAM_TARGETS))
    labels, target_labels = _labels(prior_columns, candidates), _labels(target_columns, targets)
    names = label_names(load_label_names(prior_root), labels, target_labels)
    if relevant_primitives:
        relevant_labels(relevant_primitives, names)  # fail before the expensive part, not after it
    selected_count(settings, len(candidates))  # likewise
    common = {"batch_size": settings.batch_size, "keep_log_var": settings.metric == "kl", "progress": progress}
    prior = encode_windows(policy, prior_columns, candidates, name="prior", **common)
    target = encode_windows(policy, target_columns, targets, name="target", **common)
    selection = select_windows(
        prior.mean, target.mean, settings, prior_log_var=prior.log_var, target_log_var=target.log_var, progress=progress
    )
    td = prior_columns.td
    picked = selection.retrieved
    info.update(
        num_prior_frames=len(prior_columns),
        num_target_frames=len(target_columns),
        num_candidates=len(candidates),
        num_target_windows=len(targets),
        num_retrieved=len(picked),
        cut=selection.cut,
    )
    result = RetrievalResult(
        prior_index=td["index"].as_subclass(Tensor)[candidates[picked]].to(torch.int64),
        distance=selection.distance[picked].float(),
        latent=prior.mean[picked],
        settings=info,
        **fingerprints,
    )
    context = ReportInputs(
        selection=selection,
        prior_mean=prior.mean,
        target_mean=target.mean,
        anchors=candidates,
        episode_start=td["episode_start"].as_subclass(Tensor)[candidates],
        primitive=labels,
        target_primitive=target_labels,
        primitive_names=names,
        relevant_primitives=relevant_primitives,
    )
    return _finish(result, output, report_dir, context)


STAGE1_HINT = (
    "Pass the `pretrained_model` folder of a skills run, e.g. outputs/train/<run>/checkpoints/last/pretrained_model "
    "(lerobot-train --policy.type=skillret --policy.stage=skills)."
)


def resolve_checkpoint(
    path: str | Path,
    hint: str = STAGE1_HINT,
    needs: str = "retrieval needs the skill encoder of a `--policy.type=skillret` stage-1 run",
) -> Path:
    """The `pretrained_model` folder of a skillret checkpoint (a run's checkpoint folder is accepted too); `hint`
    says which checkpoint to pass, `needs` why a skillret one."""
    path = Path(path)
    if (path / "pretrained_model").is_dir():
        path = path / "pretrained_model"
    if (path / PRETRAINED).is_dir():  # a run's output_dir
        raise FileNotFoundError(f"{path} is a training run's folder: pass its checkpoint {path / PRETRAINED}.")
    if not path.is_dir():
        state = "is a file, not a checkpoint folder" if path.exists() else "does not exist"
        raise FileNotFoundError(f"Checkpoint {path} {state}. {hint}")
    checkpoint_fingerprint(path)  # raises a clear error when config.json or model.safetensors is missing
    kind = read_json(path / "config.json").get("type")
    if kind != "skillret":
        raise ValueError(f"{path} is a `{kind}` checkpoint, not a skillret one: {needs}.")
    return path


def load_skill_model(path: str | Path, device: str | None = None) -> SkillRetPolicy:
    """The stage-1 policy in eval mode on `device` (default: the checkpoint's own, if available)."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.utils.device_utils import is_torch_device_available

    from lerobot_skillret.policy.modeling_skillret import SkillRetPolicy

    path = resolve_checkpoint(path)
    config = PreTrainedConfig.from_pretrained(path)
    if device is not None:
        if not is_torch_device_available(device):  # raises ValueError for a name that is no device
            raise ValueError(f"device {device!r} is not available on this machine; use --device cpu")
        config.device = device
    policy = SkillRetPolicy.from_pretrained(path, config=config)
    if policy.image_keys:
        raise ValueError(
            f"The checkpoint encodes camera observations {policy.image_keys}; retrieval reads windows from the "
            "datasets' low-dim columns only. Train the skill model on low-dim observations for retrieval."
        )
    return policy.eval()


def _fingerprints(checkpoint: Path, prior: str, target: str) -> dict[str, str]:
    """What a retrieval file is checked against later: its stage-1 checkpoint and both datasets' contents."""
    return {
        "checkpoint_fingerprint": checkpoint_fingerprint(checkpoint),
        "prior_fingerprint": prior,
        "target_fingerprint": target,
    }


def choose_anchors(num_frames: int, count: int | str, rng: torch.Generator) -> Tensor:
    """`count` distinct frames drawn uniformly (sorted, for memory locality), or every frame."""
    if num_frames == 0:
        raise ValueError("The dataset has no frames to draw windows from.")
    if count == EVERY_WINDOW or count >= num_frames:
        return torch.arange(num_frames)
    return torch.randperm(num_frames, generator=rng)[:count].sort().values


def _labels(columns: EpisodeColumns, anchors: Tensor) -> Tensor | None:
    if PRIMITIVE_KEY not in columns.features:
        return None
    return columns.td[PRIMITIVE_KEY].as_subclass(Tensor)[anchors].to(torch.int64)


def encode_windows(
    policy: SkillRetPolicy,
    columns: EpisodeColumns,
    anchors: Tensor,
    *,
    batch_size: int,
    keep_log_var: bool,
    progress: bool,
    name: str,
) -> Encoded:
    """Encoder (mean, log_var) of the H-step windows at `anchors`, in batches, without autograd."""
    from lerobot_skillret.data.windows import WindowSampler

    keys = [*policy.low_dim_keys, "action"]
    missing = [key for key in keys if key not in columns.features]
    if missing:
        raise KeyError(
            f"The {name} dataset {columns.repo_id} lacks {missing}, which the skill model was trained on; "
            f"it has {sorted(columns.features)}. Use datasets with the stage-1 observation layout."
        )
    # history=1: the encoder reads only the H steps from the anchor, so the F-1 earlier frames are not gathered.
    sampler = WindowSampler(columns, history=1, horizon=policy.config.horizon, keys=keys)
    dim = policy.config.latent_dim
    mean = torch.empty(len(anchors), dim)
    log_var = torch.empty(len(anchors), dim) if keep_log_var else None
    starts = range(0, len(anchors), batch_size)
    with torch.inference_mode():
        for start in tqdm(starts, desc=f"encoding {name} windows", disable=not progress, unit="batch"):
            window = sampler.gather(anchors[start : start + batch_size])
            batch_mean, batch_log_var = policy.encode_skill(dict(window.items()))
            mean[start : start + batch_size] = batch_mean.float().cpu()
            if log_var is not None:
                log_var[start : start + batch_size] = batch_log_var.float().cpu()
    return Encoded(mean=mean, log_var=log_var)


def select_windows(
    prior_mean: Tensor,
    target_mean: Tensor,
    settings: RetrievalSettings,
    *,
    prior_log_var: Tensor | None = None,
    target_log_var: Tensor | None = None,
    progress: bool = False,
) -> Selection:
    """Score the N candidate latents against the M target latents and pick round(r * N) of them (`settings.mode`).

    `settings` must be resolved; the log-variances are read by the "kl" metric only.
    """
    settings.validate()
    log_vars = (prior_log_var, target_log_var) if settings.metric == "kl" else (None, None)
    engine = NearestTarget(target_mean, log_vars[1], metric=settings.metric)
    num = prior_mean.shape[0]
    count = selected_count(settings, num)
    # Nearest-target indices cost ~30% of the pass: get them for all rows only when most rows are retrieved
    # anyway; otherwise only for the retrieved rows, afterwards.
    with_nearest = count > num // 4
    scores = engine.score(
        prior_mean, log_vars[0], chunk_size=settings.chunk_size, with_nearest=with_nearest, progress=progress
    )
    distance = _distance(scores.value.to(torch.float64), settings.metric)
    if settings.mode == "random":
        retrieved = torch.randperm(num, generator=generator(settings.seed, STREAM_RANDOM))[:count].clone()
    else:  # nearest, all (count = N), none (count = 0)
        exact = (
            (lambda rows: engine.exact(prior_mean, log_vars[0], rows, settings.chunk_size)) if settings.exact else None
        )
        retrieved, values = smallest(scores, count, exact)
        distance[retrieved] = _distance(values, settings.metric)  # float64-settled values near the cut
    retrieved = retrieved[torch.sort(distance[retrieved], stable=True).indices]
    if scores.nearest is not None:
        nearest = scores.nearest[retrieved]
    else:
        log_var = None if log_vars[0] is None else log_vars[0][retrieved]
        nearest = engine.score(
            prior_mean[retrieved], log_var, chunk_size=settings.chunk_size, with_nearest=True
        ).nearest
    return Selection(distance=distance, retrieved=retrieved, nearest=nearest)


def selected_count(settings: RetrievalSettings, num_candidates: int) -> int:
    """How many candidates `settings` retrieves (0 for mode "none"); refuses an r that rounds to no window, since a
    file that selects nothing would turn stage 2 into the no-retrieval ablation without a word."""
    if settings.mode == "none":
        return 0
    count = retrieval_count(settings.fraction, num_candidates)
    if count == 0:
        raise ValueError(
            f"r = {settings.fraction:g} of {num_candidates:,} prior windows retrieves no window (round(r * N) = 0): "
            "raise --fraction or use more prior data (or --mode none for the no-retrieval ablation)."
        )
    return count


def retrieval_count(fraction: float, num_candidates: int) -> int:
    """K = round(r * candidates) (Algorithm 2's n); r is checked by `RetrievalSettings.validate`."""
    return round(fraction * num_candidates)


def _distance(value: Tensor, metric: str) -> Tensor:
    """Reported distance: the L2 norm (kernels work with its square), or the symmetric KL itself."""
    return value.clamp(min=0.0).sqrt() if metric == "l2" else value.clamp(min=0.0)


def _finish(
    result: RetrievalResult, output: str | Path | None, report_dir: str | Path | None, inputs: ReportInputs | None
) -> RetrievalResult:
    """Write the report (staged in a temporary folder, moved into place whole), then the retrieval file (atomic):
    a kill at any point leaves no partial report, and never a retrieval file without its report."""
    if report_dir is not None:
        with staged_dir(report_dir) as staging:
            write_report(staging, result, inputs)
    if output is not None:
        result.save(output)
        log.info("wrote %d retrieved windows to %s", len(result), output)
    return result
