"""Skill windows from a LeRobotDataset, thousands of times faster than `__getitem__` with `delta_timestamps`.

Skill pre-training and retrieval need millions of (history F, horizon H) windows. `LeRobotDataset.__getitem__`
builds each one through Python lists and HF `datasets` row access (milliseconds per window). Here:

- `EpisodeColumns` exports the low-dim columns ONCE, column-wise, from the Arrow table behind `ds.hf_dataset`
  (pyarrow `flatten().to_numpy()`, never `__getitem__`), adds per-frame episode bounds, and stores the result as a
  memory-mapped TensorDict cached on disk, keyed by `dataset_fingerprint(root)` (rebuilt when the dataset changes).
  The cache is built in a temporary folder and renamed into place, so a concurrent reader sees either no cache or
  a complete one.
- `WindowSampler` draws anchors uniformly over frames (not over episodes: long episodes are not under-sampled) and
  gathers windows by clamped index arithmetic plus one `np.take` per key (microseconds per window; measured side
  by side by `benchmarks/windows_throughput.py`, figures in the README).

Why not torchrl: its `SliceSampler` picks an episode first (not uniform over frames) and pads only on the right;
torchrl 0.14's `Sequence` sample unit has the right semantics but is measurably slower than the index arithmetic
here (numbers: `benchmarks/windows_throughput.py --torchrl`). Why NumPy for the gathers: they must stay fast when
torch's intra-op threads compete with other work for the cores (training, other processes). Advanced indexing
`x[idx2d]` was measured 100x slower there and even `index_select` swung from 0.1 to 30 ms per batch of 256, while
`np.take` is single-threaded by construction; the sampler never changes the process-wide thread settings.

Camera windows (optional, `WindowSampler(..., frames=FrameReader(...))`): images and videos cannot live in the
column table, so `FrameReader` decodes them through LeRobot's own readers (the HF image column, its
`DatasetReader._query_videos` for videos), once per distinct frame of a batch: overlapping windows share their
frames, whereas `__getitem__` decodes F+H-1 frames per window. Decoding itself dominates, so the gain is modest at random anchors (4.5 vs
5.4 ms per F=H=10 window of one 8x8 camera) and grows with overlap.

Semantics equal LeRobot's: observation keys get frames anchor-(F-1) .. anchor+H-1, every other key (`action`, and
any extra low-dim key asked for) gets anchor .. anchor+H-1; positions outside the anchor's episode repeat the
episode's first/last frame and are flagged True in `<key>_is_pad`. Values are RAW dataset values (images as
LeRobot decodes them: float (C, H, W) in [0, 1], no image transforms): normalisation belongs to the policy.
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import torch
from tensordict import TensorDict

from lerobot_skillret.data.fingerprint import dataset_fingerprint
from lerobot_skillret.files import read_json

log = logging.getLogger(__name__)
CACHE_DIRNAME = ".skillret_cache"
CACHE_VERSION = 2  # bump when the cache layout or the exported columns change
BOUND_KEYS = ("episode_start", "episode_end")
_REQUIRED_KEYS = ("index", "episode_index", "frame_index")
_SKIPPED_DTYPES = ("image", "video", "string")
_INFO_FILE = "columns.json"


@dataclass
class EpisodeColumns:
    """A LeRobotDataset's low-dim columns as one TensorDict [num_frames], plus per-frame episode bounds.

    Row i is global frame i (LeRobot's `index` runs 0..N-1, so retrieval results index rows directly).
    `td` holds every exported feature under its LeRobot name with per-frame shape `features[name]` (scalar
    features, shape (1,) in LeRobot, are stored per frame as (), like `__getitem__` returns them) and int64
    `episode_start` / `episode_end`: the global index of the first frame / one past the last frame of the frame's
    episode.
    """

    td: TensorDict
    features: dict[str, tuple[int, ...]]
    fps: int
    fingerprint: str
    repo_id: str

    def __len__(self) -> int:
        return int(self.td.batch_size[0])

    @classmethod
    def from_dataset(
        cls, repo_id: str, root: str | Path, cache_dir: Path | None = None, keys: list[str] | None = None
    ) -> EpisodeColumns:
        """Load the cached columns of the dataset at `root`, exporting them first if absent or stale.

        The cache lives in `cache_dir` (default `<root>/.skillret_cache/`). `keys` restricts the exported features
        (default: every float/int/bool feature that is not an image/video); `index`, `episode_index` and
        `frame_index` are always exported.
        """
        root = Path(root)
        _check_root(root)
        fingerprint = dataset_fingerprint(root)
        cache_dir = Path(cache_dir) if cache_dir is not None else root / CACHE_DIRNAME
        wanted = None if keys is None else sorted(set(keys) | set(_REQUIRED_KEYS))
        name = f"columns-v{CACHE_VERSION}-{fingerprint}" + ("" if wanted is None else f"-{_keys_tag(wanted)}")
        final = cache_dir / name
        if (final / _INFO_FILE).is_file():
            try:
                return cls._load(final)
            except (ValueError, OSError, RuntimeError, KeyError, TypeError) as error:  # rebuilt, never trusted
                log.warning("the column cache %s is damaged (%s): rebuilding it", final, error)
                shutil.rmtree(final, ignore_errors=True)
        _build_cache(repo_id, root, fingerprint, wanted, cache_dir, final)
        _remove_stale(cache_dir, keep=name, root=root)
        return cls._load(final)

    @classmethod
    def _load(cls, folder: Path) -> EpisodeColumns:
        info = read_json(folder / _INFO_FILE)
        # a column file cut short (a copy, a full disk) would be mapped with zeros in its missing part, silently (the
        # mapping even extends the file), so the sizes are checked against the export's before mapping
        short = [name for name, size in info["bytes"].items() if _file_size(folder / "td" / name) < size]
        if short:
            raise ValueError(f"the column file(s) {short} are shorter than when written")
        td = TensorDict.load_memmap(folder / "td")
        return cls(
            td=td,
            features={k: tuple(v) for k, v in info["features"].items()},
            fps=int(info["fps"]),
            fingerprint=info["fingerprint"],
            repo_id=info["repo_id"],
        )


def _check_root(root: Path) -> None:
    if not (root / "meta" / "info.json").is_file():
        raise FileNotFoundError(
            f"No LeRobotDataset at {root} (missing meta/info.json). Pass the dataset's local root folder "
            "(the one holding meta/ and data/), e.g. the output folder of `skillret-generate`."
        )
    info = read_json(root / "meta" / "info.json")
    if not isinstance(info, dict):
        problem = f"it holds a {type(info).__name__}, not LeRobot's mapping of dataset facts"
        raise _damaged_metadata(root / "meta" / "info.json", problem)
    if info.get("total_frames", 0) == 0:
        raise ValueError(
            f"The LeRobotDataset at {root} has zero frames: record or generate at least one episode "
            "(add_frame + save_episode, then finalize) before sampling windows from it."
        )


def _damaged_metadata(path: Path, problem: str) -> ValueError:
    """`path`: the metadata file or folder (meta/) that LeRobot could not read."""
    return ValueError(
        f"The dataset's metadata {path} is damaged ({problem}): restore it from a copy or regenerate the dataset "
        "(skillret-generate, or LeRobotDataset.create + save_episode + finalize)."
    )


def _file_size(path: Path) -> int:
    return path.stat().st_size if path.is_file() else -1


def _keys_tag(keys: list[str]) -> str:
    return hashlib.sha1("\n".join(keys).encode()).hexdigest()[:8]


def _column_to_numpy(column: pa.ChunkedArray, num_frames: int, shape: tuple[int, ...]) -> np.ndarray:
    """A (possibly nested fixed-size-list) Arrow column as a (num_frames, *shape) array, column-wise."""
    array = column.combine_chunks()
    while pa.types.is_fixed_size_list(array.type) or pa.types.is_list(array.type):
        array = array.flatten()
    values = array.to_numpy(zero_copy_only=False)
    return values.reshape((num_frames, *shape))


def _export(repo_id: str, root: Path, wanted: list[str] | None) -> tuple[TensorDict, dict]:
    """Read the dataset once through LeRobot's loader and return (columns TensorDict, info dict)."""
    from datasets.exceptions import DatasetGenerationError
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        dataset = LeRobotDataset(repo_id, root=root)
    except (DatasetGenerationError, pa.ArrowInvalid) as error:
        raise ValueError(
            f"Cannot read the data files of the dataset at {root} ({error.__cause__ or error}): a parquet file under "
            "data/ is truncated or corrupt (a copy, a full disk). Regenerate the dataset or restore its files."
        ) from None
    except (TypeError, AttributeError, KeyError) as error:  # LeRobot's metadata reader on fields missing or mistyped
        raise _damaged_metadata(root / "meta", str(error)) from None
    num_frames = len(dataset.hf_dataset)
    lowdim = {k: ft for k, ft in dataset.features.items() if ft["dtype"] not in _SKIPPED_DTYPES}
    if wanted is not None:
        missing = [k for k in wanted if k not in lowdim]
        if missing:
            raise KeyError(
                f"Dataset {repo_id} at {root} has no low-dim feature(s) {missing}; available: {sorted(lowdim)}. "
                "Fix the `keys` argument (image/video features cannot be exported)."
            )
        lowdim = {k: lowdim[k] for k in wanted}
    table = dataset.hf_dataset.data.table
    columns: dict[str, torch.Tensor] = {}
    features: dict[str, tuple[int, ...]] = {}
    for key, ft in lowdim.items():
        shape = tuple(ft["shape"])
        shape = () if shape == (1,) else shape
        values = _column_to_numpy(table.column(key), num_frames, shape)
        if np.issubdtype(values.dtype, np.floating):
            _check_finite(key, values, table, root)
        columns[key] = torch.from_numpy(np.require(values, requirements=["C", "W"]))  # Arrow buffers are read-only
        features[key] = shape
    start, end = _episode_bounds(columns["index"], columns["episode_index"], root)
    columns["episode_start"], columns["episode_end"] = start, end
    td = TensorDict(columns, batch_size=[num_frames])
    info = {"features": features, "fps": int(dataset.fps), "repo_id": repo_id}
    return td, info


def _check_finite(key: str, values: np.ndarray, table: pa.Table, root: Path) -> None:
    bad = ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)
    if bad.any():
        frame = int(np.argmax(bad))
        episode = table.column("episode_index")[frame].as_py()
        raise ValueError(
            f"Column '{key}' of the dataset at {root} has NaN/inf values ({int(bad.sum())} frames), first at "
            f"global frame {frame} (episode {episode}). Fix the data: re-generate or drop that episode "
            "(NaN would silently poison the normalisation statistics and every window that touches it)."
        )


def _check_row_index(index: torch.Tensor | np.ndarray, root: Path) -> None:
    n = len(index)
    if not np.array_equal(np.asarray(index), np.arange(n)):
        raise ValueError(
            f"The 'index' column of the dataset at {root} is not 0..{n - 1} in row order; windows and retrieval "
            "indices rely on it. Re-write the dataset with LeRobotDataset.create/add_frame/save_episode."
        )


def _episode_bounds(index: torch.Tensor, episode: torch.Tensor, root: Path) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-frame global [start, end) of the frame's episode; episodes must be contiguous runs of rows."""
    _check_row_index(index, root)
    n = len(index)
    change = torch.nonzero(episode[1:] != episode[:-1]).flatten() + 1
    starts = torch.cat([torch.zeros(1, dtype=torch.long), change])
    ends = torch.cat([change, torch.tensor([n])])
    if len(torch.unique(episode[starts])) != len(starts):
        raise ValueError(
            f"Episodes of the dataset at {root} are not contiguous runs of rows (an episode_index reappears "
            "after another episode). Re-write the dataset so each episode's frames are consecutive."
        )
    lengths = ends - starts
    return torch.repeat_interleave(starts, lengths), torch.repeat_interleave(ends, lengths)


def _build_cache(
    repo_id: str, root: Path, fingerprint: str, wanted: list[str] | None, cache_dir: Path, final: Path
) -> None:
    """Export into a private temporary folder, then rename it into place (atomic on one filesystem)."""
    log.info("exporting the low-dim columns of %s to %s (once per dataset version)", root, final)
    td, info = _export(repo_id, root, wanted)
    info["fingerprint"] = fingerprint
    info["root"] = str(root.resolve())
    cache_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{final.name}-{uuid.uuid4().hex[:6]}-", dir=cache_dir))
    try:
        td.memmap_(tmp / "td")
        info["bytes"] = {path.name: path.stat().st_size for path in (tmp / "td").glob("*.memmap")}  # as written
        (tmp / _INFO_FILE).write_text(json.dumps(info, indent=1))
        try:
            tmp.rename(final)
        except OSError:
            if not (final / _INFO_FILE).is_file():  # not a concurrent builder that won the race: a real error
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _remove_stale(cache_dir: Path, keep: str, root: Path) -> None:
    """Drop this dataset's caches of older contents or cache versions; never another dataset's (a `cache_dir` may be
    shared). Open memmaps of a running reader survive unlinking on POSIX."""
    _, version, fingerprint = keep.split("-")[:3]
    for old in cache_dir.glob("columns-*"):
        info = old / _INFO_FILE
        if old.name == keep or not info.is_file() or read_json(info).get("root") != str(root.resolve()):
            continue
        if old.name.split("-")[1:3] != [version, fingerprint]:
            shutil.rmtree(old, ignore_errors=True)


class FrameReader:
    """Camera frames (image or video features) of a local LeRobotDataset by global frame index.

    Decoding is LeRobot's own, so frames are bit-identical to `LeRobotDataset.__getitem__`'s: image features through
    the HF dataset's image column, video features through its `DatasetReader._query_videos` (one decoder call per
    episode and batch, at the frames' stored timestamps).
    """

    def __init__(
        self, repo_id: str, root: str | Path, keys: list[str] | None = None, video_backend: str | None = None
    ) -> None:
        """`keys`: camera features to read (default all); `video_backend`: LeRobot's (e.g. "pyav" where torchcodec
        cannot load FFmpeg), None = LeRobot's default."""
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        root = Path(root)
        _check_root(root)
        self.dataset = LeRobotDataset(repo_id, root=root, video_backend=video_backend)
        cameras = list(self.dataset.meta.camera_keys)
        keys = cameras if keys is None else list(keys)
        missing = [k for k in keys if k not in cameras]
        if missing or not keys:
            raise KeyError(
                f"{missing or 'No'} camera feature(s) in dataset {repo_id} at {root}; its image/video features are "
                f"{cameras}. Fix the `keys` argument (low-dim features come from EpisodeColumns)."
            )
        self.keys = keys
        self._video_keys = [k for k in keys if k in self.dataset.meta.video_keys]
        table = self.dataset.hf_dataset.data.table
        n = len(self.dataset.hf_dataset)
        _check_row_index(_column_to_numpy(table.column("index"), n, ()), root)
        self._episode = _column_to_numpy(table.column("episode_index"), n, ())
        self._timestamp = _column_to_numpy(table.column("timestamp"), n, ())

    def __len__(self) -> int:
        return len(self._episode)

    def read(self, rows: np.ndarray) -> dict[str, torch.Tensor]:
        """Frames at global indices `rows` (any shape S): `{key: (*S, C, H, W)}`, each distinct row decoded once."""
        rows = np.asarray(rows, dtype=np.int64)
        unique, inverse = np.unique(rows.ravel(), return_inverse=True)
        frames = {}
        for key in self.keys:
            if key not in self._video_keys:
                frames[key] = torch.stack(list(self.dataset.hf_dataset[key][unique.tolist()]))
        if self._video_keys:
            decoded: dict[str, list[torch.Tensor]] = {key: [] for key in self._video_keys}
            for episode in np.unique(self._episode[unique]):  # `unique` is sorted, so episodes come in row order
                in_episode = unique[self._episode[unique] == episode]
                timestamps = self._timestamp[in_episode].tolist()
                query = dict.fromkeys(self._video_keys, timestamps)
                for key, value in self.dataset.reader._query_videos(query, int(episode)).items():
                    decoded[key].append(value if len(in_episode) > 1 else value.unsqueeze(0))  # it squeezes n=1
            frames.update({key: torch.cat(parts) for key, parts in decoded.items()})
        return {
            key: value[torch.from_numpy(inverse)].reshape(*rows.shape, *value.shape[1:])
            for key, value in frames.items()
        }


def _warn_short_episodes(columns: EpisodeColumns, horizon: int) -> None:
    """Episodes shorter than a window are kept, padded past their end (as LeRobot pads, and the seed does): say
    so, since every window of such an episode is partly padding."""
    firsts = np.unique(_numpy_view(columns.td["episode_start"]))
    lengths = _numpy_view(columns.td["episode_end"])[firsts] - firsts
    short = int((lengths < horizon).sum())
    if short:
        log.warning(
            "%d of %d episodes of %s are shorter than the window (H=%d; shortest %d frames): their windows are "
            "padded past the episode's end, and the padded steps are masked out of the losses and of retrieval. "
            "Record longer episodes or lower --policy.horizon if that is not intended.",
            short,
            len(lengths),
            columns.repo_id,
            horizon,
            int(lengths.min()),
        )


def _numpy_view(tensor: torch.Tensor) -> np.ndarray:
    """A NumPy view of a (memory-mapped) tensor's storage."""
    return tensor.as_subclass(torch.Tensor).numpy()


class WindowSampler:
    """Uniform (history F, horizon H) windows over the frames of an `EpisodeColumns` table.

    `keys` defaults to every `observation.*` column plus `action`. Observation keys get F+H-1 steps (delta indices
    -(F-1)..H-1, LeRobot's `observation_delta_indices`), every other key H steps (0..H-1). With `frames`, its
    camera keys are gathered too, as observation keys ((B, F+H-1, C, H, W) plus `<key>_is_pad`); `frames` must
    read the same dataset as `columns`.
    """

    def __init__(
        self,
        columns: EpisodeColumns,
        history: int,
        horizon: int,
        keys: list[str] | None = None,
        seed: int | None = None,
        frames: FrameReader | None = None,
    ) -> None:
        if history < 1 or horizon < 1:
            raise ValueError(f"history (F) and horizon (H) must be >= 1, got history={history}, horizon={horizon}")
        available = [k for k in columns.features if k not in _REQUIRED_KEYS]
        if keys is None:
            keys = [k for k in available if k.startswith("observation.")]
            keys += ["action"] if "action" in columns.features else []
        missing = [k for k in keys if k not in columns.features]
        if missing or not keys:
            raise KeyError(
                f"Window keys {missing or keys} are not low-dim columns of {columns.repo_id}; available: "
                f"{available}. Fix the `keys` argument (or export them with EpisodeColumns.from_dataset(keys=...))."
            )
        if frames is not None and len(frames) != len(columns):
            raise ValueError(
                f"`frames` reads {len(frames)} frames but the columns of {columns.repo_id} have {len(columns)}: "
                "build the FrameReader on the same dataset (repo_id and root) as the EpisodeColumns."
            )
        self.columns, self.frames = columns, frames
        self.history, self.horizon, self.keys = history, horizon, list(keys)
        _warn_short_episodes(columns, horizon)
        # NumPy views of the memory-mapped columns (same pages, no copy): see `gather` for why NumPy.
        self._data = {k: _numpy_view(columns.td[k]) for k in (*self.keys, *BOUND_KEYS, "episode_index")}
        self._obs_offsets = np.arange(-(history - 1), horizon)
        self._act_offsets = np.arange(0, horizon)
        self.generator = torch.Generator()
        if seed is None:
            self.generator.seed()
        else:
            self.generator.manual_seed(seed)

    def __len__(self) -> int:
        return len(self.columns)

    def sample_anchors(self, batch_size: int) -> torch.Tensor:
        """`batch_size` global frame positions drawn uniformly (with replacement) over all frames."""
        return torch.randint(0, len(self.columns), (batch_size,), generator=self.generator)

    def _check_anchors(self, anchors: torch.Tensor) -> torch.Tensor:
        anchors = torch.as_tensor(anchors, dtype=torch.long).flatten()
        n = len(self.columns)
        if anchors.numel() and (int(anchors.min()) < 0 or int(anchors.max()) >= n):
            raise IndexError(
                f"anchors must be global frame positions in [0, {n}), got {int(anchors.min())}..{int(anchors.max())}"
            )
        return anchors

    def gather(self, anchors: torch.Tensor) -> TensorDict:
        """Windows at `anchors` as TensorDict[B]: `<key>` (B, T, *shape), `<key>_is_pad` (B, T), `index`,
        `episode_index` (of the anchor), with T = F+H-1 for observation (and camera) keys and H otherwise."""
        anchors = self._check_anchors(anchors)
        index = anchors.numpy()
        start = self._data["episode_start"][index][:, None]
        end = self._data["episode_end"][index][:, None]
        windows = {}
        if self.frames is not None:
            pos = index[:, None] + self._obs_offsets[None, :]
            frames = self.frames.read(np.clip(pos, start, end - 1))
            is_pad = torch.from_numpy((pos < start) | (pos >= end))
            for key, value in frames.items():
                windows[key] = value
                windows[f"{key}_is_pad"] = is_pad
        for offsets, keys in (
            (self._obs_offsets, [k for k in self.keys if k.startswith("observation.")]),
            (self._act_offsets, [k for k in self.keys if not k.startswith("observation.")]),
        ):
            if not keys:
                continue
            pos = index[:, None] + offsets[None, :]
            is_pad = torch.from_numpy((pos < start) | (pos >= end))
            flat = np.clip(pos, start, end - 1).ravel()
            for key in keys:
                column = self._data[key]
                # np.take, not index_select: see the module docstring (thread oversubscription).
                values = np.take(column, flat, axis=0).reshape(*pos.shape, *column.shape[1:])
                windows[key] = torch.from_numpy(values)
                windows[f"{key}_is_pad"] = is_pad
        windows["index"] = anchors
        windows["episode_index"] = torch.from_numpy(self._data["episode_index"][index])
        return TensorDict(windows, batch_size=[len(anchors)])

    def sample(self, batch_size: int) -> TensorDict:
        """`gather(sample_anchors(batch_size))`."""
        return self.gather(self.sample_anchors(batch_size))

    def sample_pair_anchors(self, anchors: torch.Tensor, max_offset: int) -> tuple[torch.Tensor, torch.Tensor]:
        """For the temporal-prediction loss: anchors2 uniform over the frames of each anchor's episode within
        +-max_offset of it (the anchor itself included), and d = anchors2 - anchors."""
        if max_offset < 0:
            raise ValueError(f"max_offset must be >= 0, got {max_offset}")
        anchors = self._check_anchors(anchors)
        low = torch.maximum(anchors - max_offset, torch.from_numpy(self._data["episode_start"][anchors.numpy()]))
        high = torch.minimum(anchors + max_offset, torch.from_numpy(self._data["episode_end"][anchors.numpy()] - 1))
        u = torch.rand(anchors.shape, generator=self.generator, dtype=torch.float64)
        anchors2 = low + torch.clamp((u * (high - low + 1)).long(), max=high - low)
        return anchors2, anchors2 - anchors
