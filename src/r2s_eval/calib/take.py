"""Reading a board take: frames of each camera and the arm's joint states, frame by frame.

Two layouts:

- a LeRobotDataset v3 (what the twin records, and what a lab records with LeRobot): every
  episode's frames in order, ``observation.state`` in the dataset's layout;
- a folder of images: ``states.csv`` (a ``frame_index`` column and one column per state feature,
  named as the world's dataset features) and ``<camera>/<frame_index>.png`` per camera
  (any zero padding, e.g. ``head_left/000003.png``).

Frames and states must pair one to one; a take where they do not is refused naming the file.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from r2s_eval.data import STATE_KEY
from r2s_eval.data.contract import read_metadata
from r2s_eval.data.dataset import camera_key
from r2s_eval.data.frames import episode_rows, read_frames
from r2s_eval.errors import DataError

STATES_FILE = "states.csv"


@dataclass
class Take:
    source: Path
    states: np.ndarray  # (frames, features), the dataset's units
    images: dict[str, list[np.ndarray]]  # per camera, one RGB image per frame


def read_take(path: str | Path, cameras: Sequence[str], state_names: Sequence[str]) -> Take:
    path = Path(path)
    if not path.is_dir():
        raise DataError(f"board take {path}: no such folder")
    if (path / STATES_FILE).is_file():
        return _read_folder(path, cameras, state_names)
    return _read_dataset(path, cameras, state_names)


def _read_dataset(path: Path, cameras, state_names) -> Take:
    meta = read_metadata(path)
    names = list(meta.features.get(STATE_KEY, {}).get("names") or [])
    if names != list(state_names):
        raise DataError(f"board take {path}: {STATE_KEY} names {names}, the world's dataset features are "
                        f"{list(state_names)}")
    states, wanted = [], []
    for episode in sorted(int(e) for e in meta.episodes["episode_index"]):
        rows = episode_rows(meta, episode, [STATE_KEY])
        ep = meta.episodes[meta.episodes["episode_index"] == episode].iloc[0]
        for camera in cameras:
            key = camera_key(camera)
            if f"videos/{key}/from_timestamp" not in ep:
                continue  # read_frames names the camera the take lacks
            span = float(ep[f"videos/{key}/to_timestamp"]) - float(ep[f"videos/{key}/from_timestamp"])
            if abs(span * meta.fps - len(rows)) > 0.5:
                raise DataError(f"board take {path}: episode {episode} has {len(rows)} joint states but "
                                f"{span * meta.fps:.0f} frames of {camera}")
        states += list(rows[STATE_KEY])
        wanted += [(episode, int(f)) for f in rows["frame_index"]]
    frames = read_frames(meta, wanted, cameras)
    images = {cam: [frames[e, f, cam] for e, f in wanted] for cam in cameras}
    return Take(path, np.stack(states).astype(float), images)


def _read_folder(path: Path, cameras, state_names) -> Take:
    table = pd.read_csv(path / STATES_FILE)
    missing = [c for c in ["frame_index", *state_names] if c not in table.columns]
    if missing:
        raise DataError(f"board take {path / STATES_FILE}: lacks columns {missing}")
    table = table.sort_values("frame_index")
    images = {}
    for camera in cameras:
        files = {int(p.stem): p for p in (path / camera).glob("*.png") if p.stem.isdigit()}
        if len(files) != len(table) or set(files) != set(table["frame_index"]):
            raise DataError(f"board take {path}: {STATES_FILE} has {len(table)} joint states, {path / camera} "
                            f"holds {len(files)} frames" + ("" if len(files) != len(table) else
                                                             " with other frame indices"))
        images[camera] = []
        for frame in table["frame_index"]:
            raw = cv2.imread(str(files[int(frame)]))
            if raw is None:
                raise DataError(f"board take {files[int(frame)]}: not a readable image")
            images[camera].append(cv2.cvtColor(raw, cv2.COLOR_BGR2RGB))
    return Take(path, table[list(state_names)].to_numpy(float), images)
