"""The LeRobotDataset v3 contract, checked file by file before anything is computed from a dataset.

``read_metadata`` reads ``meta/`` strictly and locally: a missing or unreadable file is an error
naming it, never a reason to ask the Hugging Face Hub (lerobot's own loader falls back to the hub
when a metadata file is missing). The ``*_problems`` functions then compare what the files hold
with what ``info.json`` declares:

* ``meta/``: unique, contiguous episode indices; the totals; every episode's tasks known to
  ``tasks.parquet``; row ranges that tile the data;
* data files: every declared feature present with its dtype and width; per episode the row count,
  the global ``index``, ``frame_index``, timestamps, and the ``task_index`` of every row;
* videos: per camera file the resolution of its frames; per episode the frame count and the
  ``from_timestamp``/``to_timestamp`` window, which must tile the file in episode order.

A problem is one line naming the file (relative to the dataset root), and the episode and camera
where it has one. Problems of the dataset as a whole are returned apart from those of single
episodes, since only the latter can be dropped.
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from r2s_eval.errors import DataError

INFO = "meta/info.json"
STATS = "meta/stats.json"
TASKS = "meta/tasks.parquet"
EPISODES_DIR = "meta/episodes"
SUPPORTED_VERSION = "v3.0"
# info.json keys every reader of the dataset relies on
INFO_KEYS = ("codebase_version", "fps", "features", "total_episodes", "total_frames", "total_tasks",
             "data_path", "video_path")
EPISODE_COLUMNS = ("episode_index", "tasks", "length", "data/chunk_index", "data/file_index",
                   "dataset_from_index", "dataset_to_index")
# Columns lerobot writes into every data file besides the declared recordings.
INDEX_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")


class DatasetValidationError(DataError):
    """The dataset cannot be used; the message lists every problem found, one per line."""


@dataclass(frozen=True)
class Problem:
    file: str  # relative to the dataset root
    text: str
    episode: int | None = None
    camera: str | None = None

    def line(self) -> str:
        where = [self.file]
        if self.episode is not None:
            where.append(f"episode {self.episode}")
        if self.camera is not None:
            where.append(f"camera {self.camera}")
        return ": ".join([*where, self.text])


@dataclass
class Problems:
    """Problems of the whole dataset (never droppable) and of single episodes."""

    dataset: list[Problem] = field(default_factory=list)
    episodes: dict[int, list[Problem]] = field(default_factory=lambda: defaultdict(list))

    def add(self, problem: Problem, whole_dataset: bool = False) -> None:
        if whole_dataset or problem.episode is None:
            self.dataset.append(problem)
        else:
            self.episodes[problem.episode].append(problem)

    def extend(self, problems: Iterable[Problem]) -> None:
        for p in problems:
            self.add(p)

    def merge(self, other: Problems) -> None:
        self.dataset += other.dataset
        for episode, problems in other.episodes.items():
            self.episodes[episode] += problems

    def lines(self) -> list[str]:
        return [p.line() for p in self.dataset] + [
            p.line() for ep in sorted(self.episodes) for p in self.episodes[ep]
        ]


def fail(root: Path, lines: list[str]) -> DatasetValidationError:
    noun = "problem" if len(lines) == 1 else "problems"
    return DatasetValidationError(f"dataset {root}: {len(lines)} {noun}:\n  " + "\n  ".join(lines))


@dataclass
class LocalMetadata:
    """``meta/`` of a local dataset, read without lerobot (and so without any hub fallback)."""

    root: Path
    info: dict[str, Any]
    tasks: pd.DataFrame  # columns: task (text), task_index
    episodes: pd.DataFrame  # one row per row of meta/episodes, plus "meta_file" (where it came from)

    @property
    def fps(self) -> float:
        return float(self.info["fps"])

    @property
    def features(self) -> dict[str, dict]:
        return self.info["features"]

    def data_file(self, chunk: int, file: int) -> str:
        return self.info["data_path"].format(chunk_index=int(chunk), file_index=int(file))

    def video_file(self, key: str, chunk: int, file: int) -> str:
        return self.info["video_path"].format(video_key=key, chunk_index=int(chunk), file_index=int(file))


def _read_json(root: Path, rel: str) -> Any:
    path = root / rel
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise fail(root, [f"{rel}: missing"]) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise fail(root, [f"{rel}: not readable JSON ({e})"]) from None


def read_parquet(root: Path, rel: str, columns: list[str] | None = None) -> pd.DataFrame:
    """A parquet file as a DataFrame; a missing or damaged file raises naming it."""
    import pyarrow as pa

    path = root / rel
    if not path.is_file():
        raise fail(root, [f"{rel}: missing"])
    try:
        return pd.read_parquet(path, columns=columns)
    except (OSError, ValueError, pa.ArrowException) as e:
        raise fail(root, [f"{rel}: not a readable parquet file ({type(e).__name__}: {e})"]) from None


def read_metadata(root: str | Path) -> LocalMetadata:
    root = Path(root)
    if not (root / INFO).is_file():
        raise DatasetValidationError(f"dataset {root}: {INFO} is missing: not a LeRobotDataset v3 (no meta/info.json)")
    info = _read_json(root, INFO)
    if not isinstance(info, dict):
        raise fail(root, [f"{INFO}: holds a {type(info).__name__}, expected a JSON object"])
    version = str(info.get("codebase_version", "?"))
    if version.split(".")[0] != SUPPORTED_VERSION.split(".")[0]:
        raise fail(root, [
            f"{INFO}: codebase_version is {version}; r2s-eval reads LeRobotDataset {SUPPORTED_VERSION} "
            "(convert older datasets with lerobot's scripts/convert_dataset_v21_to_v30.py)"
        ])
    lacking = [k for k in INFO_KEYS if k not in info]
    if lacking:
        raise fail(root, [f"{INFO}: lacks {lacking}"])
    if (root / STATS).exists():
        stats = _read_json(root, STATS)
        if not isinstance(stats, dict):
            raise fail(root, [f"{STATS}: holds a {type(stats).__name__}, expected a JSON object"])

    tasks = read_parquet(root, TASKS)
    if "task_index" not in tasks.columns:
        raise fail(root, [f"{TASKS}: has no task_index column"])
    tasks = tasks.rename_axis("task").reset_index() if "task" not in tasks.columns else tasks.reset_index(drop=True)

    files = sorted((root / EPISODES_DIR).glob("chunk-*/file-*.parquet"))
    if not files:
        raise fail(root, [f"{EPISODES_DIR}/: missing, or holds no chunk-*/file-*.parquet"])
    parts = []
    for path in files:
        rel = str(path.relative_to(root))
        part = read_parquet(root, rel)
        lacking = [c for c in EPISODE_COLUMNS if c not in part.columns]
        if lacking:
            raise fail(root, [f"{rel}: lacks columns {lacking}"])
        part = part[[c for c in part.columns if not c.startswith("stats/")]]
        parts.append(part.assign(meta_file=rel))
    episodes = pd.concat(parts, ignore_index=True)
    return LocalMetadata(root, info, tasks, episodes)


# ---------------------------------------------------------------------------- meta/
def metadata_problems(meta: LocalMetadata) -> list[Problem]:
    """Indices, totals and tasks of meta/ (all problems of the whole dataset)."""
    out: list[Problem] = []
    eps = meta.episodes
    idx = eps["episode_index"].astype(int)
    for value, count in idx.value_counts().items():
        if count > 1:
            files = sorted(set(eps.loc[idx == value, "meta_file"]))
            out.append(Problem(", ".join(files), f"appears in {count} rows", episode=int(value)))
    expected = set(range(len(idx.unique())))
    missing, extra = sorted(expected - set(idx)), sorted(set(idx) - expected)
    if missing or extra:
        out.append(Problem(EPISODES_DIR, f"episode indices are not 0..{len(expected) - 1}: "
                                         f"missing {missing[:10]}, unexpected {extra[:10]}"))

    texts = list(meta.tasks["task"].astype(str))
    task_idx = meta.tasks["task_index"].astype(int)
    if len(set(texts)) != len(texts):
        out.append(Problem(TASKS, "a task text appears more than once"))
    if sorted(task_idx) != list(range(len(task_idx))):
        out.append(Problem(TASKS, f"task_index values are not 0..{len(task_idx) - 1}: {sorted(task_idx)[:10]}"))
    known = set(texts)
    for row in eps.itertuples(index=False):
        listed = [str(t) for t in row.tasks]
        if not listed:
            out.append(Problem(row.meta_file, "lists no task", episode=int(row.episode_index)))
        for text in listed:
            if text not in known:
                out.append(Problem(row.meta_file, f"task {text!r} is not in {TASKS}", episode=int(row.episode_index)))
        span = int(row.dataset_to_index) - int(row.dataset_from_index)
        if span != int(row.length):
            out.append(Problem(row.meta_file, f"dataset_from_index..dataset_to_index spans {span} rows but length "
                                              f"is {int(row.length)}", episode=int(row.episode_index)))

    info = meta.info
    unique = eps.drop_duplicates("episode_index")  # a duplicated row is reported above, not again here
    totals = {"total_episodes": len(unique), "total_frames": int(unique["length"].sum()),
              "total_tasks": len(meta.tasks)}
    for key, actual in totals.items():
        if int(info[key]) != actual:
            out.append(Problem(INFO, f"{key} is {info[key]} but the metadata holds {actual}"))
    split = (info.get("splits") or {}).get("train")
    if split is not None and split != f"0:{len(unique)}":
        out.append(Problem(INFO, f"splits.train is {split!r}, expected '0:{len(unique)}'"))
    return out


def feature_problems(meta: LocalMetadata, state_key: str, action_key: str, feature_names: list[str],
                     camera_keys: list[str], fps: int) -> list[Problem]:
    """What info.json declares against what the world's robot expects: the state and action entries
    named as its ``robot.features`` map them (same names, same order), its cameras, its control rate."""
    out: list[Problem] = []
    if float(meta.info["fps"]) != float(fps):
        out.append(Problem(INFO, f"fps is {meta.info['fps']}, the world's robot.control_hz is {fps}"))
    feats = meta.features
    dim = len(feature_names)
    for key in (state_key, action_key):
        if key not in feats:
            out.append(Problem(INFO, f"feature {key!r} is missing"))
            continue
        shape, names = tuple(feats[key].get("shape") or ()), feats[key].get("names")
        if isinstance(names, dict):  # older datasets: {"motors": [...]}
            names = next(iter(names.values()), None)
        if names is not None and list(names) != list(feature_names):
            unmapped = [n for n in names if n not in feature_names]
            absent = [n for n in feature_names if n not in names]
            detail = (f"; not in robot.features: {unmapped}" if unmapped else "") + (
                f"; robot.features has, the dataset lacks: {absent}" if absent else "")
            out.append(Problem(INFO, f"feature {key!r} names {list(names)}, the world's robot.features map "
                                     f"{list(feature_names)}{detail or ' (another order)'}"))
        elif shape != (dim,):
            out.append(Problem(INFO, f"feature {key!r} has shape {shape}, the world's robot.features map ({dim},)"))
        if feats[key].get("dtype") not in ("float32", "float64"):
            out.append(Problem(INFO, f"feature {key!r} has dtype {feats[key].get('dtype')!r}, expected float32"))
    for key in camera_keys:
        if key not in feats:
            out.append(Problem(INFO, f"camera feature {key!r} is missing"))
        elif feats[key].get("dtype") != "video":
            out.append(Problem(INFO, f"camera feature {key!r} is stored as {feats[key].get('dtype')!r}, expected video"))
        elif len(feats[key].get("shape") or ()) != 3:
            out.append(Problem(INFO, f"camera feature {key!r} has shape {feats[key].get('shape')}, expected (h, w, 3)"))
    for key in INDEX_FEATURES:
        if key not in feats:
            out.append(Problem(INFO, f"feature {key!r} is missing"))
    return out


# ---------------------------------------------------------------------------- data files
def _arrow_dtype_name(t) -> str:
    import pyarrow as pa

    if pa.types.is_floating(t) or pa.types.is_integer(t) or pa.types.is_boolean(t):
        return {"float": "float32", "double": "float64", "halffloat": "float16", "bool": "bool"}.get(str(t), str(t))
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        return "string"
    return str(t)


def _column_problems(rel: str, table, feats: dict[str, dict]) -> tuple[list[Problem], dict[str, np.ndarray]]:
    """Declared non-video features against one data file's columns: presence, dtype, and per row width.

    Returns the file's problems and, per list column, the width of every row (for per-episode checks).
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    out, widths = [], {}
    for key, feat in feats.items():
        if feat.get("dtype") in ("video", "image"):
            continue
        if key not in table.column_names:
            out.append(Problem(rel, f"column {key!r} declared in {INFO} is missing"))
            continue
        col_type = table.schema.field(key).type
        shape = tuple(feat.get("shape") or ())
        listed = pa.types.is_list(col_type) or pa.types.is_large_list(col_type) or pa.types.is_fixed_size_list(col_type)
        value_type = col_type.value_type if listed else col_type
        if _arrow_dtype_name(value_type) != feat.get("dtype"):
            out.append(Problem(rel, f"column {key!r} holds {_arrow_dtype_name(value_type)}, "
                                    f"{INFO} declares {feat.get('dtype')}"))
        if listed:
            if len(shape) != 1:
                out.append(Problem(rel, f"column {key!r} holds vectors, {INFO} declares shape {shape}"))
                continue
            widths[key] = pc.list_value_length(table.column(key)).to_numpy(zero_copy_only=False)
        elif shape not in ((), (1,)):
            out.append(Problem(rel, f"column {key!r} holds one value per frame, {INFO} declares shape {shape}"))
    return out, widths


def data_problems(meta: LocalMetadata) -> tuple[Problems, dict[int, pd.DataFrame]]:
    """Every data file against meta/episodes; returns the problems and each sound episode's rows."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    problems = Problems()
    frames: dict[int, pd.DataFrame] = {}
    feats = meta.features
    task_text = dict(zip(meta.tasks["task_index"].astype(int), meta.tasks["task"].astype(str)))
    eps = meta.episodes.drop_duplicates("episode_index")
    fps = meta.fps
    total_rows = 0
    for (chunk, file), group in eps.groupby(["data/chunk_index", "data/file_index"]):
        rel = meta.data_file(chunk, file)
        ids = [int(e) for e in group["episode_index"]]
        path = meta.root / rel
        if not path.is_file():
            for e in ids:
                problems.add(Problem(rel, "data file is missing", episode=e))
            continue
        try:
            table = pq.read_table(path)
        except (OSError, ValueError, pa.ArrowException) as e:
            for ep in ids:
                problems.add(Problem(rel, f"not a readable parquet file ({type(e).__name__}: {e})", episode=ep))
            continue
        total_rows += table.num_rows
        file_problems, widths = _column_problems(rel, table, feats)
        problems.extend(file_problems)
        if any(k not in table.column_names for k in INDEX_FEATURES):
            continue
        data = table.to_pandas()
        for key, w in widths.items():
            data[f"__width__{key}"] = w
        listed = set(ids)
        strays = sorted(set(data["episode_index"].astype(int)) - listed)
        if strays:
            problems.add(Problem(rel, f"holds rows of episodes {strays[:10]} that meta/episodes places elsewhere "
                                      "or does not list"))
        by_episode = dict(tuple(data.groupby("episode_index")))
        for row in group.itertuples(index=False):
            e = int(row.episode_index)
            rows = by_episode.get(e)
            rows = rows.sort_values("frame_index") if rows is not None else None
            ep_problems = _episode_row_problems(rel, e, row, rows, feats, widths, task_text, fps)
            problems.extend(ep_problems)
            if not ep_problems:
                frames[e] = rows.drop(columns=[c for c in rows.columns if c.startswith("__width__")])
    if total_rows and total_rows != int(meta.info["total_frames"]) and not problems.episodes:
        problems.add(Problem(INFO, f"total_frames is {meta.info['total_frames']} but the data files hold {total_rows} rows"))
    return problems, frames


def _episode_row_problems(rel: str, e: int, row, rows: pd.DataFrame | None, feats: dict, widths: dict,
                          task_text: dict[int, str], fps: float) -> list[Problem]:
    """One episode's rows of one data file (sorted by frame_index) against meta/episodes and info.json."""
    length = int(row.length)
    if rows is None or not len(rows):
        return [Problem(rel, "has no rows in this data file", episode=e)]
    out = []
    if len(rows) != length:
        out.append(Problem(rel, f"holds {len(rows)} rows, meta/episodes says length {length}", episode=e))
    frame_index = rows["frame_index"].to_numpy(dtype=np.int64)
    if not np.array_equal(frame_index, np.arange(len(rows))):
        out.append(Problem(rel, "frame_index is not 0, 1, 2, ... in order", episode=e))
    index = rows["index"].to_numpy(dtype=np.int64)
    start = int(row.dataset_from_index)
    if not np.array_equal(index, np.arange(start, start + len(rows))):
        out.append(Problem(rel, f"index column runs {index.min()}..{index.max()}, meta/episodes says "
                                f"{start}..{int(row.dataset_to_index) - 1}", episode=e))
    times = rows["timestamp"].to_numpy(dtype=np.float64)
    expected = frame_index / fps
    off = np.abs(times - expected)
    if len(off) and off.max() > 0.25 / fps:
        first = int(np.argmax(off > 0.25 / fps))
        out.append(Problem(rel, f"timestamp at frame {first} is {times[first]:.3f} s, expected "
                                f"frame_index/fps = {expected[first]:.3f} s", episode=e))
    for key, w in widths.items():
        want = tuple(feats[key].get("shape") or ())[0]
        bad = rows[f"__width__{key}"].to_numpy() != want
        if bad.any():
            got = int(rows[f"__width__{key}"].to_numpy()[bad][0])
            out.append(Problem(rel, f"{key} holds {got} values in {int(bad.sum())} frame(s), {INFO} declares "
                                    f"({want},)", episode=e))
    listed = [str(t) for t in row.tasks]
    carried = sorted({int(t) for t in rows["task_index"]})
    texts = [task_text.get(t) for t in carried]
    if None in texts:
        out.append(Problem(rel, f"rows carry task_index {carried}, not all of which are in {TASKS}", episode=e))
    elif sorted(set(texts)) != sorted(set(listed)):
        out.append(Problem(rel, f"rows carry task_index {carried} ({texts}) but meta/episodes lists {listed}",
                           episode=e))
    return out


# ---------------------------------------------------------------------------- videos
@dataclass
class VideoScan:
    """Every frame time that decodes in one video file, its frame size, and the images asked for."""

    times_s: np.ndarray
    size_hw: tuple[int, int] | None
    error: str | None
    images: dict[float, np.ndarray]


def scan_video(path: Path, keep_times_s: list[float], tolerance_s: float) -> VideoScan:
    """Decode a whole file once (files hold many episodes): cheaper than a seek per episode."""
    import av

    times, images, error, size = [], {}, None, None
    wanted = np.array(sorted(keep_times_s))
    try:
        with av.open(str(path)) as container:
            for frame in container.decode(video=0):
                t = float(frame.time)
                times.append(t)
                size = size or (int(frame.height), int(frame.width))
                if len(wanted) and np.min(np.abs(wanted - t)) < tolerance_s:
                    images[float(wanted[np.argmin(np.abs(wanted - t))])] = frame.to_ndarray(format="rgb24")
    except (av.error.FFmpegError, OSError) as exc:
        error = f"{type(exc).__name__}: {exc}"
    return VideoScan(np.array(times), size, error, images)


def video_problems(meta: LocalMetadata, cameras: dict[str, str], first_frame_key: str | None
                   ) -> tuple[Problems, dict[int, np.ndarray]]:
    """Per camera (`cameras`: feature key -> camera name) and video file: resolution, each episode's
    frame count and timestamp window. Returns the problems and the first frame of `first_frame_key`
    of every episode whose video is sound."""
    problems = Problems()
    first_frames: dict[int, np.ndarray] = {}
    fps = meta.fps
    tol = 0.5 / fps
    eps = meta.episodes.drop_duplicates("episode_index")
    for key, cam in cameras.items():
        columns = [f"videos/{key}/{c}" for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")]
        lacking = [c for c in columns if c not in eps.columns]
        if lacking:
            problems.add(Problem(EPISODES_DIR, f"lacks columns {lacking}", camera=cam))
            continue
        declared = tuple(meta.features[key]["shape"][:2])
        for (chunk, file), group in eps.groupby(columns[:2]):
            rel = meta.video_file(key, chunk, file)
            ids = [int(e) for e in group["episode_index"]]
            path = meta.root / rel
            if not path.is_file():
                for e in ids:
                    problems.add(Problem(rel, "video file is missing", episode=e, camera=cam))
                continue
            group = group.sort_values(columns[2])
            starts = group[columns[2]].astype(float).tolist()
            scan = scan_video(path, starts if key == first_frame_key else [], tol)
            if scan.size_hw is not None and scan.size_hw != declared:
                for e in ids:
                    problems.add(Problem(rel, f"frames are {scan.size_hw[0]}x{scan.size_hw[1]} (h x w), {INFO} "
                                              f"declares {declared[0]}x{declared[1]}", episode=e, camera=cam))
                continue
            expected_end = 0.0
            for ep in group.to_dict("records"):
                e, n = int(ep["episode_index"]), int(ep["length"])
                t0, t1 = float(ep[columns[2]]), float(ep[columns[3]])
                ep_problems = []
                if abs(t0 - expected_end) > tol:
                    ep_problems.append(f"from_timestamp is {t0:.3f} s, but the file's previous episode ends at "
                                       f"{expected_end:.3f} s")
                if abs((t1 - t0) - n / fps) > tol:
                    ep_problems.append(f"from_timestamp..to_timestamp spans {t1 - t0:.3f} s, but {n} frames at "
                                       f"{fps:g} fps take {n / fps:.3f} s")
                expected_end = t1
                decoded = int(np.sum((scan.times_s > t0 - tol) & (scan.times_s < t0 + (n - 0.5) / fps)))
                if decoded < n:
                    reason = f" ({scan.error})" if scan.error else ""
                    ep_problems.append(f"only {decoded} of {n} frames decode{reason}")
                for text in ep_problems:
                    problems.add(Problem(rel, text, episode=e, camera=cam))
                if not ep_problems and key == first_frame_key:
                    image = scan.images.get(t0)
                    if image is None:
                        problems.add(Problem(rel, f"no frame at from_timestamp {t0:.3f} s", episode=e, camera=cam))
                    else:
                        first_frames[e] = image
            if not scan.error and len(scan.times_s):
                file_end = float(scan.times_s.max()) + 1.0 / fps
                if abs(file_end - expected_end) > tol:
                    last = int(group["episode_index"].iloc[-1])
                    problems.add(Problem(rel, f"the file's frames end at {file_end:.3f} s but its last episode's "
                                              f"to_timestamp is {expected_end:.3f} s", episode=last, camera=cam))
    return problems, first_frames
