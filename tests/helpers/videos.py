"""Rollout folders with tiny mp4 videos whose brightness stands for how well the policy did, and
real simulator episodes of a policy that succeeds and one that fails."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from r2s_eval.rollout.mp4 import write_video


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


SIM_TASK = "cup_on_plate"


def render_sim_episodes(root: Path, max_steps: int = 100) -> pd.DataFrame:
    """Two real episodes of the simulator on cup_on_plate (128x128 head_left, same initial poses):
    the scripted operator (succeeds) and a frozen policy that holds its first state (fails).

    Returns their episode table (videos under `root`, plus trajectory parquets that a video judge
    must never open); file names spell out policy and outcome, as a careless writer might.
    """
    from r2s_eval.rollout import run_episode

    from tests.helpers.policies import FrozenPolicy, OperatorPolicy
    from tests.helpers.worlds import bundled_env

    env = bundled_env(SIM_TASK, image_size=(128, 128), cameras=("head_left",))
    rows = []
    try:
        poses = env.sample_initial_poses(np.random.default_rng(4))
        policies = (("ScriptedOperator", OperatorPolicy(env)), ("FrozenPolicy", FrozenPolicy()))
        for n, (policy, pol) in enumerate(policies):
            pol.reset()
            result = run_episode(env, pol, poses, seed=1, max_steps=max_steps, video_camera="head_left")
            outcome = "SUCCESS" if result.success else "FAILURE"
            stem = f"{policy}/{SIM_TASK}_0_{outcome}"
            (root / policy).mkdir(parents=True, exist_ok=True)
            write_video(root / f"{stem}.mp4", result.frames, fps=10)
            result.trajectory.to_parquet(root / f"{stem}.parquet")
            rows.append({
                "episode_id": f"sim{n}", "policy": policy, "arm": "sim", "task": SIM_TASK, "init_id": 0,
                "instruction": env.task.instruction, "success": bool(result.success), "length": result.length,
                "video_path": f"{stem}.mp4", "trajectory_path": f"{stem}.parquet",
            })
    finally:
        env.close()
    return pd.DataFrame(rows)
