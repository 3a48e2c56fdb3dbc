"""The episode store: finished episodes kept one folder each as they end, so an interrupted set
of rollouts resumes with the episodes it had not finished, then gathered into the rollout folder.

Both rollout paths write through it, the MuJoCo worlds' (``r2s_eval.rollout.candidate``) and
LIBERO's (``r2s_eval.libero.rollout``): per episode a video, a trajectory and a row.
``load_episodes`` reads finished rollout folders back as one table.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from r2s_eval.rollout.batch import PlannedEpisode
from r2s_eval.rollout.mp4 import VideoWriter
from r2s_eval.utils.io import atomic_dir, write_json, write_parquet


def episode_store(out: Path, identity: str) -> Path:
    """The sibling folder that keeps finished episodes across interrupted runs."""
    store = out.with_name(f".{out.name}.episodes")
    key_file = store / "identity.json"
    if store.exists() and (not key_file.is_file() or json.loads(key_file.read_text()) != identity):
        shutil.rmtree(store)  # made by another config or policy: nothing in it is ours
    store.mkdir(parents=True, exist_ok=True)
    key_file.write_text(json.dumps(identity))
    return store


class EpisodeFolder:
    """A running episode's files, in a temporary folder of the store that is renamed to the
    episode id once the episode is whole; its video is encoded as the frames come."""

    def __init__(self, store: Path, planned: PlannedEpisode, fps: int):
        self.store, self.planned = store, planned
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{planned.episode_id}.", suffix=".tmp", dir=store))
        self.video = VideoWriter(self.tmp / f"{planned.episode_id}.mp4", fps)

    def add(self, frame: np.ndarray) -> None:
        self.video.add(frame)

    def finish(self, row: dict, trajectory: pd.DataFrame) -> None:
        ep = self.planned.episode_id
        self.video.close()
        write_parquet(self.tmp / f"{ep}.parquet", trajectory)
        write_json(self.tmp / "row.json", row)
        os.replace(self.tmp, self.store / ep)

    def abort(self) -> None:
        self.video.abort()
        shutil.rmtree(self.tmp, ignore_errors=True)


def collect_episodes(out: Path, store: Path, planned: list[PlannedEpisode]) -> pd.DataFrame:
    """Move the finished episodes into ``out`` (atomically) and drop the store."""
    rows = []
    with atomic_dir(out) as tmp:
        (tmp / "videos").mkdir()
        (tmp / "trajectories").mkdir()
        for p in planned:
            ep = p.episode_id
            row = json.loads((store / ep / "row.json").read_text())
            stats = row.pop("policy_stats")
            shutil.copyfile(store / ep / f"{ep}.mp4", tmp / row["video_path"])
            shutil.copyfile(store / ep / f"{ep}.parquet", tmp / row["trajectory_path"])
            rows.append((row, stats))
        episodes = pd.DataFrame([r for r, _ in rows])
        totals = {k: sum(s[k] for _, s in rows) for k in ("steps", "model_calls", "inference_s")}
        write_parquet(tmp / "episodes.parquet", episodes, metadata={"stage": "rollout", "policy_stats": totals})
    shutil.rmtree(store)
    return episodes


def load_episodes(rollout_dirs: list[str]) -> pd.DataFrame:
    """The rollout folders' ``episodes.parquet`` as one table; media paths become relative to the
    working dir (each row's folder joined to its video and trajectory path)."""
    frames = []
    for folder in rollout_dirs:
        table = pd.read_parquet(Path(folder) / "episodes.parquet")
        for column in ("video_path", "trajectory_path"):
            table[column] = [str(Path(folder) / p) for p in table[column]]
        frames.append(table)
    return pd.concat(frames, ignore_index=True)
