"""Ingest: check a teleop dataset before anything is computed from it, and index its episodes.

The whole LeRobotDataset v3 contract is checked (``contract.py``), then what this robot and
suite need: the state and action widths, the cameras, the frame rate, known task instructions,
episode lengths and finite values. Every problem is one line naming the file, the episode and
the camera. A problem of the dataset as a whole fails the stage; a bad episode either fails it
(default) or, with `drop_bad_episodes`, is left out of the index and listed in the report.
Everything downstream reads the index, so a dropped episode is never used.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from r2s_eval.data.contract import (
    DatasetValidationError,
    Problem,
    Problems,
    data_problems,
    fail,
    feature_problems,
    metadata_problems,
    read_metadata,
    video_problems,
)
from r2s_eval.data.dataset import ACTION_KEY, STATE_KEY, camera_key

log = logging.getLogger(__name__)

__all__ = ["DatasetValidationError", "IngestSpec", "ingest_dataset"]


@dataclass
class IngestSpec:
    cameras: list[str]
    feature_names: list[str]  # the state's and action's entries, as the world's robot.features name them
    fps: int
    # instruction text -> task key of the suite; episodes with other instructions are errors
    tasks: dict[str, str]
    first_frame_camera: str
    min_length: int = 10
    max_length: int = 10_000
    drop_bad_episodes: bool = False
    check_videos: bool = True
    # feature name -> the range its values can take, in the dataset's units (the world's joint
    # limits through robot.features); a feature mostly outside it is recorded in another unit
    feature_ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)


RANGE_MARGIN = 0.1  # of a joint's range: calibration slack and servo overshoot at the limits
MIN_SHARE_IN_RANGE = 0.5  # below this share of the frames inside its range, a feature's unit is wrong


def _episode_problems(meta, ep: dict, frames: pd.DataFrame, spec: IngestSpec) -> list[Problem]:
    """What this suite needs of one episode whose files are sound."""
    out = []
    e, length = int(ep["episode_index"]), int(ep["length"])
    if not spec.min_length <= length <= spec.max_length:
        out.append(Problem(ep["meta_file"], f"length {length} outside [{spec.min_length}, {spec.max_length}]", e))
    task = _task_text(ep)
    if task not in spec.tasks:
        out.append(Problem(ep["meta_file"], f"task {task!r} is not one of the configured tasks {sorted(spec.tasks)}", e))
    data_file = meta.data_file(ep["data/chunk_index"], ep["data/file_index"])
    for key in (STATE_KEY, ACTION_KEY):
        values = np.stack(frames[key].to_numpy())
        bad = ~np.isfinite(values)
        if bad.any():
            rows = np.unique(np.nonzero(bad)[0])
            out.append(Problem(data_file, f"{key} has NaN/inf in {len(rows)} frame(s), first at frame {int(rows[0])}", e))
    return out


def range_problems(frames: dict[int, pd.DataFrame], spec: IngestSpec, data_file: str) -> list[Problem]:
    """Features whose recorded state lies mostly outside what the world's joint can reach: a unit
    the world's mapping gets wrong (degrees as radians, -100..100 as degrees), which no calibration
    downstream could tell from a badly placed robot."""
    if not spec.feature_ranges or not frames:
        return []
    state = np.concatenate([np.stack(f[STATE_KEY].to_numpy()) for f in frames.values()])
    out = []
    for i, name in enumerate(spec.feature_names):
        if name not in spec.feature_ranges:
            continue
        lo, hi = spec.feature_ranges[name]
        margin = RANGE_MARGIN * (hi - lo)
        values = state[:, i]
        share = float(np.mean((values >= lo - margin) & (values <= hi + margin)))
        if share < MIN_SHARE_IN_RANGE:
            out.append(Problem(data_file, f"{STATE_KEY} {name!r} lies inside its joint's range [{lo:.4g}, {hi:.4g}] "
                                          f"(dataset units, through robot.features[{i}]) in {share:.0%} of "
                                          f"{len(values)} frames (recorded {values.min():.4g} .. {values.max():.4g}): "
                                          "the world's mapping has the wrong unit (check its scale and offset)"))
    return out


def _task_text(ep: dict) -> str:
    tasks = list(ep["tasks"])
    return str(tasks[0]) if tasks else ""


def ingest_dataset(root: str | Path, repo_id: str, spec: IngestSpec, first_frames_dir: str | Path) -> tuple[pd.DataFrame, dict]:
    """Validate the dataset at `root`; return the episode index and a report.

    The index has one row per usable episode: episode_index, task (key), instruction,
    length, first_frame (PNG of the first frame of `spec.first_frame_camera`).
    Raises ``DatasetValidationError`` listing every problem, one per line.
    """
    root = Path(root)
    first_frames_dir = Path(first_frames_dir)
    meta = read_metadata(root)
    cameras = {camera_key(c): c for c in spec.cameras}
    first_key = camera_key(spec.first_frame_camera)
    if first_key not in cameras:
        cameras[first_key] = spec.first_frame_camera
    problems = Problems()
    problems.extend(feature_problems(meta, STATE_KEY, ACTION_KEY, spec.feature_names, list(cameras),
                                     spec.fps))
    if problems.dataset:  # the files cannot be checked against features this robot cannot use
        raise fail(root, problems.lines())
    for p in metadata_problems(meta):
        problems.add(p, whole_dataset=True)

    found, frames = data_problems(meta)
    checked = cameras if spec.check_videos else {first_key: cameras[first_key]}
    found_videos, first_frames = video_problems(meta, checked, first_key)
    problems.merge(found)
    problems.merge(found_videos)
    for p in range_problems(frames, spec, "data/*.parquet"):
        problems.add(p, whole_dataset=True)
    if problems.dataset:
        raise fail(root, problems.lines())

    rows = []
    first_frames_dir.mkdir(parents=True, exist_ok=True)
    episodes = meta.episodes.sort_values("episode_index").to_dict("records")
    for ep in episodes:
        e = int(ep["episode_index"])
        if e in problems.episodes:
            continue
        ep_problems = _episode_problems(meta, ep, frames[e], spec)
        if ep_problems:
            problems.episodes[e] += ep_problems
            continue
        frame_path = first_frames_dir / f"episode_{e:06d}.png"
        cv2.imwrite(str(frame_path), cv2.cvtColor(first_frames[e], cv2.COLOR_RGB2BGR))
        instruction = _task_text(ep)
        rows.append({"episode_index": e, "task": spec.tasks[instruction], "instruction": instruction,
                     "length": int(ep["length"]), "first_frame": frame_path.name})
    lines = problems.lines()
    if lines and not spec.drop_bad_episodes:
        raise fail(root, lines)
    if not rows:
        raise fail(root, ["no usable episode is left", *lines])
    for line in lines:
        log.warning("dropped: %s", line)
    index = pd.DataFrame(rows)
    report = {
        "dataset": str(root),
        "repo_id": repo_id,
        "fps": int(meta.fps),
        "episodes_total": len(episodes),
        "episodes_usable": int(len(index)),
        "frames_usable": int(index["length"].sum()),
        "dropped": {str(e): [p.line() for p in ps] for e, ps in sorted(problems.episodes.items())},
        "episodes_per_task": index.groupby("task").size().to_dict(),
    }
    return index, report
