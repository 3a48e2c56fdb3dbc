"""Ingest: check a teleop dataset before anything is computed from it, and index its episodes.

Every problem is reported with the episode it concerns; one bad episode either fails the
stage (default) or, with `drop_bad_episodes`, is left out of the index and listed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import av
import cv2
import numpy as np
import pandas as pd

from r2s_eval.data.dataset import ACTION_KEY, STATE_KEY, camera_key, decode_frame, episode_table, open_metadata

log = logging.getLogger(__name__)


class DatasetValidationError(ValueError):
    """The dataset cannot be used; the message lists every problem found."""


@dataclass
class IngestSpec:
    cameras: list[str]
    state_dim: int
    action_dim: int
    fps: int
    # instruction text -> task key of the suite; episodes with other instructions are errors
    tasks: dict[str, str]
    first_frame_camera: str
    min_length: int = 10
    max_length: int = 10_000
    drop_bad_episodes: bool = False
    check_videos: bool = True
    extra: dict = field(default_factory=dict)


def _dataset_problems(meta, spec: IngestSpec) -> list[str]:
    problems = []
    if int(meta.fps) != int(spec.fps):
        problems.append(f"fps is {meta.fps}, expected {spec.fps}")
    feats = meta.features
    for key, dim in ((STATE_KEY, spec.state_dim), (ACTION_KEY, spec.action_dim)):
        if key not in feats:
            problems.append(f"feature {key!r} is missing")
        elif tuple(feats[key]["shape"]) != (dim,):
            problems.append(f"feature {key!r} has shape {tuple(feats[key]['shape'])}, expected ({dim},)")
    for cam in spec.cameras:
        key = camera_key(cam)
        if key not in feats:
            problems.append(f"camera feature {key!r} is missing")
        elif feats[key]["dtype"] != "video":
            problems.append(f"camera feature {key!r} is stored as {feats[key]['dtype']!r}, expected video")
    return problems


def _episode_problems(ep: pd.Series, frames: pd.DataFrame, spec: IngestSpec) -> list[str]:
    problems = []
    length = int(ep["length"])
    if len(frames) != length:
        problems.append(f"metadata says {length} frames but the data file holds {len(frames)}")
    if not spec.min_length <= length <= spec.max_length:
        problems.append(f"length {length} outside [{spec.min_length}, {spec.max_length}]")
    if ep["task"] not in spec.tasks:
        problems.append(f"task {ep['task']!r} is not one of the configured tasks {sorted(spec.tasks)}")
    for key in (STATE_KEY, ACTION_KEY):
        if key not in frames.columns:
            continue
        values = np.stack(frames[key].to_numpy()) if len(frames) else np.zeros((0, 0))
        bad = ~np.isfinite(values)
        if bad.any():
            rows = np.unique(np.nonzero(bad)[0])
            problems.append(f"{key} has NaN/inf in {len(rows)} frame(s), first at frame {int(rows[0])}")
    if len(frames) > 1:
        steps = np.diff(frames["timestamp"].to_numpy(dtype=float))
        if np.any(np.abs(steps - 1.0 / spec.fps) > 0.25 / spec.fps):
            problems.append(f"timestamps are not spaced 1/fps={1.0 / spec.fps:.4f} s apart")
    return problems


@dataclass
class _VideoScan:
    """Every frame time that decodes in one video file, and the images asked for."""

    times_s: np.ndarray
    error: str | None
    images: dict[float, np.ndarray]


def _scan_video(path: Path, keep_times_s: list[float], tolerance_s: float) -> _VideoScan:
    """Decode a whole file once (files hold many episodes): cheaper than a seek per episode."""
    times, images, error = [], {}, None
    wanted = np.array(sorted(keep_times_s))
    try:
        with av.open(str(path)) as container:
            for frame in container.decode(video=0):
                t = float(frame.time)
                times.append(t)
                if len(wanted) and np.min(np.abs(wanted - t)) < tolerance_s:
                    images[float(wanted[np.argmin(np.abs(wanted - t))])] = frame.to_ndarray(format="rgb24")
    except (av.error.FFmpegError, OSError) as exc:
        error = f"{type(exc).__name__}: {exc}"
    return _VideoScan(np.array(times), error, images)


def _video_problems(root: Path, meta, episodes: pd.DataFrame, spec: IngestSpec, first_frame_key: str):
    """Per-episode video problems and first frames, from one sequential decode per file."""
    problems: dict[int, list[str]] = {}
    first_frames: dict[int, np.ndarray] = {}
    tol = 0.5 / meta.fps
    for cam in spec.cameras:
        key = camera_key(cam)
        if key not in meta.features:
            continue
        loc = [f"videos/{key}/chunk_index", f"videos/{key}/file_index"]
        for (chunk, file), group in episodes.groupby(loc):
            path = root / meta.video_path.format(video_key=key, chunk_index=chunk, file_index=file)
            starts = group[f"videos/{key}/from_timestamp"].astype(float).tolist()
            scan = _scan_video(path, starts if key == first_frame_key else [], tol)
            for _, ep in group.iterrows():
                idx, t0 = int(ep["episode_index"]), float(ep[f"videos/{key}/from_timestamp"])
                n = int(ep["length"])
                decoded = int(np.sum((scan.times_s > t0 - tol) & (scan.times_s < t0 + (n - 0.5) / meta.fps)))
                if decoded < n:
                    reason = f" ({scan.error})" if scan.error else ""
                    problems.setdefault(idx, []).append(
                        f"camera {cam}: only {decoded} of {n} frames decode from {path.name}{reason}"
                    )
                elif key == first_frame_key:
                    image = scan.images.get(t0)
                    expected = tuple(meta.features[key]["shape"])
                    if image is None or image.shape != expected:
                        got = None if image is None else image.shape
                        problems.setdefault(idx, []).append(f"camera {cam}: first frame is {got}, expected {expected}")
                    else:
                        first_frames[idx] = image
    return problems, first_frames


def ingest_dataset(root: str | Path, repo_id: str, spec: IngestSpec, first_frames_dir: str | Path) -> tuple[pd.DataFrame, dict]:
    """Validate the dataset at `root`; return the episode index and a report.

    The index has one row per usable episode: episode_index, task (key), instruction,
    length, first_frame (PNG of the first frame of `spec.first_frame_camera`).
    """
    root = Path(root)
    first_frames_dir = Path(first_frames_dir)
    try:
        meta = open_metadata(root, repo_id)
    except FileNotFoundError as exc:
        raise DatasetValidationError(str(exc)) from exc
    problems = _dataset_problems(meta, spec)
    if problems:
        raise DatasetValidationError(f"dataset {root}: " + "; ".join(problems))

    episodes = episode_table(meta)
    first_key = camera_key(spec.first_frame_camera)
    if spec.check_videos:
        bad, first_frames = _video_problems(root, meta, episodes, spec, first_key)
    else:
        bad, first_frames = {}, {}
    data_cache: dict[Path, pd.DataFrame] = {}
    rows = []
    first_frames_dir.mkdir(parents=True, exist_ok=True)
    for _, ep in episodes.iterrows():
        idx = int(ep["episode_index"])
        path = root / meta.data_path.format(chunk_index=ep["data/chunk_index"], file_index=ep["data/file_index"])
        if path not in data_cache:
            data_cache[path] = pd.read_parquet(path)
        data = data_cache[path]
        frames = data[data["episode_index"] == idx].sort_values("frame_index")
        ep_problems = _episode_problems(ep, frames, spec) + bad.get(idx, [])
        if ep_problems:
            bad[idx] = ep_problems
            continue
        image = first_frames[idx] if idx in first_frames else decode_frame(root, meta, idx, spec.first_frame_camera, 0)
        frame_path = first_frames_dir / f"episode_{idx:06d}.png"
        cv2.imwrite(str(frame_path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        rows.append(
            {
                "episode_index": idx,
                "task": spec.tasks[ep["task"]],
                "instruction": ep["task"],
                "length": int(ep["length"]),
                "first_frame": frame_path.name,
            }
        )
    messages = [f"episode {idx}: {p}" for idx, ps in sorted(bad.items()) for p in ps]
    if bad and not spec.drop_bad_episodes:
        raise DatasetValidationError(
            f"dataset {root} has {len(bad)} bad episode(s):\n  " + "\n  ".join(messages)
        )
    if not rows:
        raise DatasetValidationError(f"dataset {root} has no usable episode:\n  " + "\n  ".join(messages))
    for message in messages:
        log.warning("dropped %s", message)
    index = pd.DataFrame(rows)
    report = {
        "dataset": str(root),
        "fps": int(meta.fps),
        "episodes_total": int(len(episodes)),
        "episodes_usable": int(len(index)),
        "frames_usable": int(index["length"].sum()),
        "dropped": {str(k): v for k, v in bad.items()},
        "episodes_per_task": index.groupby("task").size().to_dict(),
    }
    return index, report
