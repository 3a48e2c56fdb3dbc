"""Rollout folders with tiny mp4 videos whose brightness stands for how well the policy did."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from r2s_eval.rollout.video import write_video


INSTRUCTIONS = {"lift": "lift the red cube", "stack": "stack the cube on the plate"}


def make_rollouts(root: Path, brightness: dict[tuple[str, str, int], float],
                  lengths: dict[tuple[str, str, int], int] | None = None) -> list[str]:
    """Rollout folders (episodes.parquet + mp4 per episode) whose names give away policy and outcome.

    `lengths`: frames per episode (12 when not given), e.g. short successes and long failures, as
    rollouts that stop soon after success give; the episode table records it as ``length``.
    """
    dirs = {}
    for n, ((policy, task, init), level) in enumerate(sorted(brightness.items())):
        folder = root / policy
        outcome = "SUCCESS" if level >= 0.6 else "FAILURE"
        rel = f"videos/{task}_{init}_{outcome}_{policy}.mp4"
        steps = (lengths or {}).get((policy, task, init), 12)
        frames = np.full((steps, 32, 32, 3), round(level * 255), dtype=np.uint8)
        frames[:, :4, :4, :] = (37 * n) % 256  # distinct content per episode, brightness within 2%
        frames[:, 0, 1, :] = (np.arange(steps) % 256)[:, None]  # and motion over time
        (folder / "videos").mkdir(parents=True, exist_ok=True)
        write_video(folder / rel, list(frames), fps=10)
        dirs.setdefault(policy, []).append({
            "episode_id": f"{policy}-ep{n:03d}", "policy": policy, "task": task, "init_id": init,
            "instruction": INSTRUCTIONS[task], "success": level >= 0.6, "length": steps, "video_path": rel,
            "trajectory_path": f"traj/{n}.parquet",
        })
    for policy, rows in dirs.items():
        pd.DataFrame(rows).to_parquet(root / policy / "episodes.parquet")
    return [str(root / p) for p in sorted(dirs)]


def scene() -> dict[tuple[str, str, int], float]:
    """GoodPolicyAlpha: bright, successful. BadPolicyBeta: dark, failed; on init 0 of each task its
    video is CONFUSING (never a letter), on init 1 HESITANT (a letter only when asked again). The
    description of GoodPolicyAlpha's lift init 3 misses a section."""
    levels = {}
    for task in INSTRUCTIONS:
        for init in range(4):
            levels[("GoodPolicyAlpha", task, init)] = 0.78 + 0.01 * init
            levels[("BadPolicyBeta", task, init)] = {0: 0.50, 1: 0.35}.get(init, 0.20)
    levels[("GoodPolicyAlpha", "lift", 3)] = 0.92
    return levels
