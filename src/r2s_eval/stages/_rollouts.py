"""Read the per-policy rollout folders back as one episode table."""

from __future__ import annotations

from pathlib import Path

import pandas as pd


def load_episodes(rollout_dirs: list[str]) -> pd.DataFrame:
    """Concatenate episodes.parquet files; media paths become relative to the working dir."""
    frames = []
    for folder in rollout_dirs:
        table = pd.read_parquet(Path(folder) / "episodes.parquet")
        for column in ("video_path", "trajectory_path"):
            table[column] = [str(Path(folder) / p) for p in table[column]]
        frames.append(table)
    return pd.concat(frames, ignore_index=True)
