"""Reading rollout folders back: one table, media paths joined to their folder."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.rollout import load_episodes


def _folder(root: Path, policy: str, n: int) -> Path:
    root.mkdir(parents=True)
    pd.DataFrame({"policy": [policy] * n, "episode_id": [f"{policy}-{i}" for i in range(n)],
                  "video_path": [f"videos/{i}.mp4" for i in range(n)],
                  "trajectory_path": [f"trajectories/{i}.parquet" for i in range(n)]}
                 ).to_parquet(root / "episodes.parquet")
    return root


def test_load_episodes_concatenates_folders_in_order_with_paths_under_each_folder(tmp_path):
    a, b = _folder(tmp_path / "a", "act", 2), _folder(tmp_path / "b", "dp", 1)
    episodes = load_episodes([str(a), str(b)])
    assert episodes["episode_id"].tolist() == ["act-0", "act-1", "dp-0"]
    assert list(episodes.index) == [0, 1, 2]
    assert episodes["video_path"].tolist() == [str(a / "videos/0.mp4"), str(a / "videos/1.mp4"), str(b / "videos/0.mp4")]
    assert episodes["trajectory_path"].iloc[2] == str(b / "trajectories/0.parquet")
