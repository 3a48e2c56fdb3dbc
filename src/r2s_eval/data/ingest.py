"""Ingest: check a teleop dataset before anything is computed from it, and index its episodes.

Every problem is reported with the episode it concerns; one bad episode either fails the
stage (default) or, with `drop_bad_episodes`, is left out of the index and listed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from r2s_eval.data.dataset import (
    ACTION_KEY,
    STATE_KEY,
    camera_key,
    decode_frame,
    episode_table,
    open_metadata,
)

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


def _episode_problems(root: Path, meta, ep: pd.Series, frames: pd.DataFrame, spec: IngestSpec) -> list[str]:
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
    if spec.check_videos and length > 0:
        for cam in spec.cameras:
            if camera_key(cam) not in meta.features:
                continue
            for frame_index in (0, length - 1):
                try:
                    image = decode_frame(root, meta, int(ep["episode_index"]), cam, frame_index)
                except Exception as exc:  # any decoder failure is a data problem here
                    problems.append(f"camera {cam}: frame {frame_index} does not decode ({type(exc).__name__}: {exc})")
                    break
                expected = tuple(meta.features[camera_key(cam)]["shape"])
                if image.shape != expected:
                    problems.append(f"camera {cam}: frame shape {image.shape}, expected {expected}")
                    break
    return problems


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
    data_cache: dict[Path, pd.DataFrame] = {}
    rows, bad = [], {}
    first_frames_dir.mkdir(parents=True, exist_ok=True)
    for _, ep in episodes.iterrows():
        idx = int(ep["episode_index"])
        path = root / meta.data_path.format(chunk_index=ep["data/chunk_index"], file_index=ep["data/file_index"])
        if path not in data_cache:
            data_cache[path] = pd.read_parquet(path)
        data = data_cache[path]
        frames = data[data["episode_index"] == idx].sort_values("frame_index")
        ep_problems = _episode_problems(root, meta, ep, frames, spec)
        if ep_problems:
            bad[idx] = ep_problems
            continue
        image = decode_frame(root, meta, idx, spec.first_frame_camera, 0)
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
