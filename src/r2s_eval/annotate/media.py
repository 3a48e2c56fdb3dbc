"""The annotation set on disk: the key table, its summary and the videos under opaque names."""

from __future__ import annotations

import shutil
from pathlib import Path

import av
import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.utils.io import atomic_dir, write_json, write_parquet


def video_fps(path: str | Path) -> float:
    """Frames per second of an mp4's first video stream (the app's frame step is 1 / fps)."""
    try:
        with av.open(str(path)) as container:
            rate = container.streams.video[0].average_rate or container.streams.video[0].base_rate
    except (av.error.FFmpegError, IndexError) as err:
        raise DataError(f"rollout video {path} cannot be read: {err}") from err
    if not rate:
        raise DataError(f"rollout video {path} states no frame rate")
    return float(rate)


def write_annotation_set(items: pd.DataFrame, summary: dict, episodes: pd.DataFrame, *, set_path: str | Path,
                         videos_dir: str | Path, summary_path: str | Path) -> pd.DataFrame:
    """Copy every video of the set to ``videos_dir`` under its token, add each side's frame rate
    (``fps_a``, ``fps_b``) to the items, and write them and the summary; returns the items.

    The videos are copied byte for byte, so the set is one folder that can be moved; the key
    table (policies, outcomes) sits beside it, and the app serves only the videos."""
    source = dict(zip(episodes["episode_id"].astype(str), episodes["video_path"].astype(str)))
    videos: dict[str, str] = {}
    for side in ("a", "b"):
        for episode, token in zip(items[f"episode_{side}"], items[f"video_{side}"]):
            if videos.setdefault(token, episode) != episode:
                raise DataError(f"video token {token} names two episodes ({videos[token]}, {episode})")
    fps: dict[str, float] = {}
    with atomic_dir(videos_dir) as tmp:
        for token, episode in sorted(videos.items()):
            src = Path(source[episode])
            if not src.is_file():
                raise DataError(f"episode {episode}: video {src} is missing")
            fps[token] = video_fps(src)
            shutil.copyfile(src, tmp / token)
    items = items.assign(fps_a=[fps[t] for t in items["video_a"]], fps_b=[fps[t] for t in items["video_b"]])
    write_parquet(set_path, items, metadata={"stage": "annotation_set", "summary": summary})
    write_json(summary_path, summary, provenance=True)
    return items
