"""EpisodeColumns / WindowSampler: windows equal LeRobot's own, anchors uniform over frames, cache behaviour."""

from __future__ import annotations

import json
import os
import re
import shutil
import threading
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from scipy import stats
from synthetic import IMAGE_KEY, make_synthetic_dataset, synthetic_features

from lerobot_skillret.data import windows
from lerobot_skillret.data.windows import EpisodeColumns, FrameReader, WindowSampler

REPO = "test/synthetic"
OBS_KEYS = ["observation.state", "observation.environment_state"]


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    # Lengths 2..30 with F+H-1 up to 13: many episodes are shorter than a window.
    return make_synthetic_dataset(tmp_path_factory.mktemp("ds") / "root", num_episodes=8, min_len=2, max_len=30)


@pytest.fixture(scope="module")
def columns(dataset_root, tmp_path_factory) -> EpisodeColumns:
    return EpisodeColumns.from_dataset(REPO, dataset_root, cache_dir=tmp_path_factory.mktemp("cache"))


def _copy_dataset(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(windows.CACHE_DIRNAME))
    return dst


def _rewrite_column(root: Path, key: str, edit) -> None:
    """Edit one float column of the (single) parquet file in place, keeping its Arrow type."""
    (path,) = sorted((root / "data").glob("*/*.parquet"))
    table = pq.read_table(path)
    column = table.column(key).combine_chunks()
    values = column.flatten().to_numpy().reshape(len(table), -1).copy()
    edit(values)
    new = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), type=pa.float32()), values.shape[1])
    table = table.set_column(table.schema.get_field_index(key), key, new)
    pq.write_table(table, path)


def test_columns_match_lerobot(dataset_root, columns):
    ds = LeRobotDataset(REPO, root=dataset_root)
    assert len(columns) == ds.num_frames
    for key in [*OBS_KEYS, "action", "primitive_index", "index", "episode_index", "frame_index", "timestamp"]:
        expected = torch.stack(list(ds.hf_dataset[key]))
        assert torch.equal(columns.td[key].as_subclass(torch.Tensor), expected), key
    assert columns.features["observation.state"] == (6,)
    assert columns.features["primitive_index"] == ()
    for ep in ds.meta.episodes:
        lo, hi = ep["dataset_from_index"], ep["dataset_to_index"]
        assert (columns.td["episode_start"][lo:hi] == lo).all()
        assert (columns.td["episode_end"][lo:hi] == hi).all()
    assert columns.fps == 20
    assert columns.fingerprint == windows.dataset_fingerprint(dataset_root)


@pytest.mark.parametrize(("history", "horizon"), [(1, 1), (3, 5), (10, 4)])
def test_windows_equal_lerobot_getitem(dataset_root, columns, history, horizon):
    fps = columns.fps
    obs_deltas = [d / fps for d in range(-(history - 1), horizon)]
    act_deltas = [d / fps for d in range(horizon)]
    delta_timestamps = {key: obs_deltas for key in OBS_KEYS}
    delta_timestamps |= {"action": act_deltas, "primitive_index": act_deltas}
    ds = LeRobotDataset(REPO, root=dataset_root, delta_timestamps=delta_timestamps)
    sampler = WindowSampler(columns, history, horizon, keys=[*OBS_KEYS, "action", "primitive_index"])
    anchors = torch.arange(len(columns))  # every frame: every episode edge, every short episode
    batch = sampler.gather(anchors)
    assert batch.batch_size == torch.Size([len(columns)])
    assert batch["observation.state"].shape == (len(columns), history + horizon - 1, 6)
    assert batch["action"].shape == (len(columns), horizon, 7)
    # F=H=1 never pads; otherwise short episodes and edges must produce padding on both sides.
    assert batch["observation.state_is_pad"].any() == (history + horizon > 2)
    assert batch["action_is_pad"].any() == (horizon > 1)
    for i in anchors.tolist():
        item = ds[i]
        for key in [*OBS_KEYS, "action", "primitive_index"]:
            assert torch.equal(batch[key][i], item[key]), (key, i)
            assert torch.equal(batch[f"{key}_is_pad"][i], item[f"{key}_is_pad"]), (key, i)
        assert batch["index"][i] == item["index"]
        assert batch["episode_index"][i] == item["episode_index"]


def test_default_keys_skip_images(tmp_path):
    root = make_synthetic_dataset(tmp_path / "img", num_episodes=2, with_images=True)
    columns = EpisodeColumns.from_dataset(REPO, root)
    assert IMAGE_KEY not in columns.features
    assert (root / windows.CACHE_DIRNAME).is_dir()  # default cache location
    sampler = WindowSampler(columns, history=2, horizon=3)
    assert set(sampler.keys) == {*OBS_KEYS, "action"}
    batch = sampler.sample(16)
    assert set(batch.keys()) == {
        *sampler.keys,
        *(f"{k}_is_pad" for k in sampler.keys),
        "index",
        "episode_index",
    }


def test_anchors_uniform_over_frames(columns):
    sampler = WindowSampler(columns, 3, 5, seed=0)
    n = len(columns)
    counts = torch.bincount(sampler.sample_anchors(200 * n), minlength=n).numpy()
    # Chi-square over frames: a bias towards short episodes (episode-first sampling) gives p ~ 0.
    assert stats.chisquare(counts).pvalue > 1e-3
    episode = columns.td["episode_index"].numpy()
    lengths = np.bincount(episode)
    share = np.bincount(episode, weights=counts) / counts.sum()
    tolerance = 5 * np.sqrt(lengths / n * (1 - lengths / n) / counts.sum())
    assert np.all(np.abs(share - lengths / n) < tolerance)
    # Same seed, same anchors; another seed, other anchors.
    assert torch.equal(
        WindowSampler(columns, 3, 5, seed=1).sample_anchors(64), WindowSampler(columns, 3, 5, seed=1).sample_anchors(64)
    )
    assert not torch.equal(sampler.sample_anchors(64), WindowSampler(columns, 3, 5, seed=2).sample_anchors(64))


@pytest.mark.parametrize("max_offset", [0, 1, 4, 100])
def test_pair_anchors_in_episode_and_offset(columns, max_offset):
    sampler = WindowSampler(columns, 3, 5, seed=0)
    anchors = torch.arange(len(columns)).repeat(200)
    anchors2, d = sampler.sample_pair_anchors(anchors, max_offset)
    assert torch.equal(anchors2 - anchors, d)
    assert d.abs().max() <= max_offset
    episode = columns.td["episode_index"].as_subclass(torch.Tensor)
    assert torch.equal(episode[anchors2], episode[anchors])
    # Uniform over the allowed range: at the middle frame of the longest episode every offset is reachable.
    start, end = columns.td["episode_start"], columns.td["episode_end"]
    mid = int(torch.argmax(end - start)) + int((end - start).max()) // 2
    allowed = torch.arange(max(int(start[mid]), mid - max_offset), min(int(end[mid]) - 1, mid + max_offset) + 1)
    hits = anchors2[anchors == mid]
    counts = torch.bincount(hits - allowed[0], minlength=len(allowed)).numpy()
    assert counts.sum() == len(hits) and len(counts) == len(allowed)
    if len(allowed) > 1:
        assert stats.chisquare(counts).pvalue > 1e-3


def test_cache_reused_then_invalidated(tmp_path, monkeypatch):
    root = make_synthetic_dataset(tmp_path / "ds", num_episodes=3)
    cache = tmp_path / "cache"
    first = EpisodeColumns.from_dataset(REPO, root, cache_dir=cache)

    def fail(*args, **kwargs):
        raise AssertionError("cache was rebuilt although the dataset did not change")

    with monkeypatch.context() as patch:
        patch.setattr(windows, "_export", fail)
        again = EpisodeColumns.from_dataset(REPO, root, cache_dir=cache)
    assert again.fingerprint == first.fingerprint
    assert torch.equal(again.td["action"], first.td["action"])

    def shift(values):
        values[5] += 1.0

    _rewrite_column(root, "action", shift)
    changed = EpisodeColumns.from_dataset(REPO, root, cache_dir=cache)
    assert changed.fingerprint != first.fingerprint
    assert torch.allclose(changed.td["action"][5], first.td["action"][5] + 1.0)
    assert torch.equal(changed.td["action"][6:], first.td["action"][6:])
    leftovers = sorted(p.name for p in cache.iterdir())
    assert leftovers == [f"columns-v{windows.CACHE_VERSION}-{changed.fingerprint}"]  # stale one removed


@pytest.mark.parametrize("damage", ["truncate", "delete", "info"])
def test_a_damaged_cache_is_rebuilt_not_read_as_zeros(tmp_path, caplog, damage):
    """A column file cut short (a copy, a full disk) was mapped with zeros in its missing part, silently."""
    root = make_synthetic_dataset(tmp_path / "ds", num_episodes=3)
    first = EpisodeColumns.from_dataset(REPO, root, cache_dir=tmp_path / "cache")
    expected = first.td["observation.state"].clone()
    (folder,) = (tmp_path / "cache").glob("columns-*")
    column = folder / "td" / "observation.state.memmap"
    if damage == "truncate":
        os.truncate(column, column.stat().st_size // 2)
    elif damage == "delete":
        column.unlink()
    else:
        (folder / "columns.json").write_text('{"features": {')
    with caplog.at_level("WARNING"):
        again = EpisodeColumns.from_dataset(REPO, root, cache_dir=tmp_path / "cache")
    assert torch.equal(again.td["observation.state"], expected)
    assert "is damaged" in caplog.text and "rebuilding it" in caplog.text


def test_shared_cache_dir_keeps_every_datasets_cache(tmp_path, monkeypatch):
    """Two datasets sharing one cache_dir never evict each other's cache."""
    cache = tmp_path / "cache"
    roots = [make_synthetic_dataset(tmp_path / f"ds{i}", num_episodes=2, seed=i) for i in range(2)]
    for root in roots:
        EpisodeColumns.from_dataset(REPO, root, cache_dir=cache)
    assert len(list(cache.glob("columns-*"))) == 2
    with monkeypatch.context() as patch:
        patch.setattr(windows, "_export", lambda *a, **k: (_ for _ in ()).throw(AssertionError("rebuilt")))
        for root in roots:
            EpisodeColumns.from_dataset(REPO, root, cache_dir=cache)


def test_concurrent_builders_publish_one_complete_cache(tmp_path, monkeypatch):
    root = make_synthetic_dataset(tmp_path / "ds", num_episodes=2)
    cache = tmp_path / "cache"
    both_exported = threading.Barrier(2, timeout=60)
    export = windows._export

    def export_then_wait(*args, **kwargs):
        result = export(*args, **kwargs)
        both_exported.wait()  # both builders hold a finished export before either renames
        return result

    monkeypatch.setattr(windows, "_export", export_then_wait)
    results, errors = [], []

    def build():
        try:
            results.append(EpisodeColumns.from_dataset(REPO, root, cache_dir=cache))
        except Exception as error:  # surfaced by the assertion below
            errors.append(error)

    threads = [threading.Thread(target=build) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors
    assert torch.equal(results[0].td["action"], results[1].td["action"])
    assert [p.name for p in cache.iterdir()] == [f"columns-v{windows.CACHE_VERSION}-{results[0].fingerprint}"]


def test_keys_subset_and_missing_key(dataset_root, tmp_path):
    sub = EpisodeColumns.from_dataset(REPO, dataset_root, cache_dir=tmp_path, keys=["action"])
    assert set(sub.features) == {"action", "index", "episode_index", "frame_index"}
    with pytest.raises(KeyError, match=r"observation\.velocity"):
        EpisodeColumns.from_dataset(REPO, dataset_root, cache_dir=tmp_path, keys=["observation.velocity"])
    with pytest.raises(KeyError, match=r"observation.state.*Fix the `keys`"):
        WindowSampler(sub, 2, 3, keys=["observation.state"])


def test_nan_column_is_named(dataset_root, tmp_path):
    root = _copy_dataset(dataset_root, tmp_path / "nan")

    def poison(values):
        values[17, 2] = np.nan

    _rewrite_column(root, "observation.state", poison)
    with pytest.raises(ValueError, match=r"'observation.state'.*global frame 17 \(episode \d+\)"):
        EpisodeColumns.from_dataset(REPO, root, cache_dir=tmp_path / "cache")
    assert not any((tmp_path / "cache").glob("columns-*"))


def test_a_truncated_parquet_file_is_named(dataset_root, tmp_path):
    root = _copy_dataset(dataset_root, tmp_path / "cut")
    (path,) = sorted((root / "data").glob("*/*.parquet"))
    path.write_bytes(path.read_bytes()[:-200])
    with pytest.raises(ValueError, match=r"data files of the dataset at .*cut .*truncated or corrupt"):
        EpisodeColumns.from_dataset(REPO, root, cache_dir=tmp_path / "cache")


def test_rows_out_of_index_order_are_refused_by_both_readers(tmp_path):
    """Windows and retrieval indices are row numbers: a dataset whose `index` column is not 0..N-1 is refused."""
    image_root = make_synthetic_dataset(tmp_path / "img", num_episodes=2, min_len=5, max_len=5, with_images=True)
    (path,) = sorted((image_root / "data").glob("*/*.parquet"))
    table = pq.read_table(path)
    index = table.column("index").to_numpy().copy()
    index[[1, 2]] = index[[2, 1]]
    pq.write_table(table.set_column(table.schema.get_field_index("index"), "index", pa.array(index)), path)
    with pytest.raises(ValueError, match=r"'index' column .* not 0\.\.9 in row order.*Re-write the dataset"):
        EpisodeColumns.from_dataset(REPO, image_root, cache_dir=tmp_path / "cache")
    with pytest.raises(ValueError, match=r"not 0\.\.9 in row order.*Re-write the dataset"):
        FrameReader(REPO, image_root)


def test_missing_root_and_empty_dataset(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"meta/info\.json"):
        EpisodeColumns.from_dataset(REPO, tmp_path / "nowhere")
    empty = LeRobotDataset.create(REPO, 20, synthetic_features(2, 2, 2, False), root=tmp_path / "e", use_videos=False)
    empty.finalize()
    with pytest.raises(ValueError, match="zero frames"):
        EpisodeColumns.from_dataset(REPO, tmp_path / "e")


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda info: [], "it holds a list"),
        (lambda info: {k: v for k, v in info.items() if k != "fps"}, "argument: 'fps'"),
        (lambda info: {**info, "features": "x"}, "'str' object has no attribute"),
    ],
)
def test_a_damaged_info_json_is_named(tmp_path, edit, problem):
    """A hand-edited or half-copied meta/info.json gave LeRobot's TypeError / AttributeError with no file named."""
    root = make_synthetic_dataset(tmp_path / "ds", num_episodes=2)
    info = root / "meta" / "info.json"
    info.write_text(json.dumps(edit(json.loads(info.read_text()))))
    named = re.escape(str(info if "holds a list" in problem else info.parent))  # LeRobot reads meta/ as a whole
    with pytest.raises(ValueError, match=f"metadata {named} is damaged \\(.*{re.escape(problem)}.*regenerate the"):
        EpisodeColumns.from_dataset(REPO, root)


def test_sampler_argument_errors(columns):
    with pytest.raises(ValueError, match="history"):
        WindowSampler(columns, 0, 5)
    sampler = WindowSampler(columns, 2, 3)
    with pytest.raises(IndexError, match="anchors"):
        sampler.gather(torch.tensor([len(columns)]))
    with pytest.raises(ValueError, match="max_offset"):
        sampler.sample_pair_anchors(torch.tensor([0]), -1)


VIDEO_KEY = "observation.images.wrist"


def _make_video_dataset(root: Path, lengths: list[int]) -> Path:
    """A tiny dataset with one VIDEO camera (the synthetic datasets store images), including a 1-frame episode."""
    features = {
        "observation.state": {"dtype": "float32", "shape": (3,), "names": None},
        "action": {"dtype": "float32", "shape": (2,), "names": None},
        VIDEO_KEY: {"dtype": "video", "shape": (32, 32, 3), "names": ["height", "width", "channels"]},
    }
    dataset = LeRobotDataset.create("test/video", 20, features, root=root, use_videos=True)
    rng = np.random.default_rng(0)
    for length in lengths:
        for _ in range(length):
            dataset.add_frame(
                {
                    "observation.state": rng.normal(size=3).astype(np.float32),
                    "action": rng.normal(size=2).astype(np.float32),
                    VIDEO_KEY: rng.integers(0, 256, (32, 32, 3), dtype=np.uint8),
                    "task": "video task",
                }
            )
        dataset.save_episode()
    dataset.finalize()
    return root


@pytest.mark.parametrize("kind", ["image", "video"])
def test_camera_windows_equal_lerobot_getitem(tmp_path, kind):
    history, horizon = 3, 4
    if kind == "image":
        repo, key = REPO, IMAGE_KEY
        root = make_synthetic_dataset(tmp_path / "img", num_episodes=3, min_len=2, max_len=12, with_images=True)
    else:
        repo, key = "test/video", VIDEO_KEY
        root = _make_video_dataset(tmp_path / "vid", [7, 1, 9])
    columns = EpisodeColumns.from_dataset(repo, root)
    backend = "pyav"  # torchcodec, LeRobot's default, needs system FFmpeg libraries this machine may lack
    sampler = WindowSampler(columns, history, horizon, frames=FrameReader(repo, root, video_backend=backend))
    anchors = torch.arange(len(columns)).flip(0)  # every frame, out of order: results must follow the anchors
    batch = sampler.gather(anchors)
    assert batch[key].shape[:2] == (len(columns), history + horizon - 1) and batch[key].dtype == torch.float32
    assert batch[f"{key}_is_pad"].any()
    fps = columns.fps
    deltas = [d / fps for d in range(-(history - 1), horizon)]
    ds = LeRobotDataset(repo, root=root, delta_timestamps={key: deltas}, video_backend=backend)
    for row, anchor in enumerate(anchors.tolist()):
        item = ds[anchor]
        assert torch.equal(batch[key][row], item[key]), (key, anchor)
        assert torch.equal(batch[f"{key}_is_pad"][row], item[f"{key}_is_pad"]), (key, anchor)
        assert torch.equal(batch["observation.state"][row, history - 1], item["observation.state"])


def test_frame_reader_errors(dataset_root, columns, tmp_path):
    with pytest.raises(KeyError, match="camera feature"):
        FrameReader(REPO, dataset_root)  # low-dim only dataset: no cameras at all
    image_root = make_synthetic_dataset(tmp_path / "img", num_episodes=1, min_len=5, max_len=5, with_images=True)
    with pytest.raises(KeyError, match=r"observation\.images\.missing"):
        FrameReader(REPO, image_root, keys=["observation.images.missing"])
    with pytest.raises(ValueError, match="same dataset"):
        WindowSampler(columns, 2, 3, frames=FrameReader(REPO, image_root))


def test_policy_window_source_decodes_videos_with_the_configured_backend(tmp_path):
    """The windows skillret fetches itself (pairs, prior, retrieved) use `--policy.video_backend`, like LeRobot's."""
    from lerobot_skillret.policy.window_source import WindowSource

    root = _make_video_dataset(tmp_path / "vid", [7, 1, 9])
    source = WindowSource("test/video", root, ["observation.state"], [VIDEO_KEY], 3, 4, video_backend="pyav")
    assert source.sampler.frames.dataset._video_backend == "pyav"
    anchors = torch.tensor([16, 7, 0])
    batch = source.gather(anchors, "cpu")
    deltas = [d / 20 for d in range(-2, 4)]
    ds = LeRobotDataset("test/video", root=root, delta_timestamps={VIDEO_KEY: deltas}, video_backend="pyav")
    for row, anchor in enumerate(anchors.tolist()):
        assert torch.equal(batch[VIDEO_KEY][row], ds[anchor][VIDEO_KEY])
        assert torch.equal(batch[f"{VIDEO_KEY}_is_pad"][row], ds[anchor][f"{VIDEO_KEY}_is_pad"])
