"""Camera frames and per-frame rows of a LeRobotDataset v3, read without lerobot.

A video file holds many episodes; each file is decoded once for every frame asked of it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from r2s_eval.data.contract import LocalMetadata, read_parquet, scan_video
from r2s_eval.data.dataset import camera_key
from r2s_eval.errors import DataError


def _episode_row(meta: LocalMetadata, episode: int) -> pd.Series:
    rows = meta.episodes[meta.episodes["episode_index"] == episode]
    if rows.empty:
        raise DataError(f"dataset {meta.root}: has no episode {episode}")
    return rows.iloc[0]


def read_frames(meta: LocalMetadata, wanted: Iterable[tuple[int, int]], cameras: Sequence[str]
                ) -> dict[tuple[int, int, str], np.ndarray]:
    """RGB frames ``{(episode, frame_index, camera): image}`` of ``wanted`` (episode, frame index)
    pairs from each camera; a camera the dataset does not record, or a frame that does not
    decode, raises naming the file, episode and frame."""
    wanted = sorted(set((int(e), int(f)) for e, f in wanted))
    by_file: dict[str, list[tuple[int, int, str, float]]] = {}
    for camera in dict.fromkeys(cameras):
        key = camera_key(camera)
        if key not in meta.features:
            raise DataError(f"dataset {meta.root}: records no camera {camera!r} ({key}); it records "
                            f"{sorted(k for k in meta.features if k.startswith('observation.images.'))}")
        for episode, frame in wanted:
            ep = _episode_row(meta, episode)
            rel = meta.video_file(key, ep[f"videos/{key}/chunk_index"], ep[f"videos/{key}/file_index"])
            t = float(ep[f"videos/{key}/from_timestamp"]) + frame / meta.fps
            by_file.setdefault(rel, []).append((episode, frame, camera, t))
    frames = {}
    for rel, items in by_file.items():
        scan = scan_video(meta.root / rel, [t for *_, t in items], 0.5 / meta.fps)
        for episode, frame, camera, t in items:
            if t not in scan.images:
                raise DataError(f"dataset {meta.root}: {rel}: no frame {frame} of episode {episode} at {t:.3f} s"
                                + (f" ({scan.error})" if scan.error else ""))
            frames[episode, frame, camera] = scan.images[t]
    return frames


def episode_rows(meta: LocalMetadata, episode: int, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """The per-frame rows of one episode (in frame order), read from its data file."""
    ep = _episode_row(meta, episode)
    rel = meta.data_file(ep["data/chunk_index"], ep["data/file_index"])
    keep = None if columns is None else list(dict.fromkeys(["episode_index", "frame_index", *columns]))
    data = read_parquet(Path(meta.root), rel, keep)
    rows = data[data["episode_index"] == episode].sort_values("frame_index").reset_index(drop=True)
    if rows.empty:
        raise DataError(f"dataset {meta.root}: {rel} holds no rows of episode {episode}")
    return rows
