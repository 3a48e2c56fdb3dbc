"""Automatic action replay: re-run recorded joint actions in the calibrated simulation.

The first attempt starts from the estimated initial poses; while the task's success check
fails, retry from poses perturbed around the estimate (uniform +-perturb_xy_m in x and y;
yaw +-perturb_yaw_rad for objects whose yaw is observable, uniform over a full turn for
rotationally symmetric ones, whose yaw the estimate cannot know), up to ``max_attempts``
attempts in all. The first successful attempt's observations, paired with the recorded
actions, become a simulated demonstration.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from r2s_eval.sim import TabletopEnv

Poses = dict[str, tuple[float, float, float]]


@dataclass
class ReplayResult:
    success: bool
    attempts: int  # attempts run, the first (unperturbed) one included
    poses: Poses  # initial poses of the last attempt
    frames: list[tuple[dict, np.ndarray]] = field(repr=False)  # (observation, action) of the last attempt


def perturb(poses: Poses, rng: np.random.Generator, xy_m: float, yaw_rad: float,
            yaw_symmetry: Mapping[str, int] | None = None) -> Poses:
    """Poses shifted uniformly by +-xy_m; yaw by +-yaw_rad, or anywhere for symmetric objects.

    Objects missing from ``yaw_symmetry`` count as having an observable yaw.
    """
    out = {}
    for name, (x, y, yaw) in poses.items():
        symmetric = yaw_symmetry is not None and yaw_symmetry.get(name, 1) == 0
        new_yaw = rng.uniform(-np.pi, np.pi) if symmetric else yaw + rng.uniform(-yaw_rad, yaw_rad)
        out[name] = (x + rng.uniform(-xy_m, xy_m), y + rng.uniform(-xy_m, xy_m), new_yaw)
    return out


def run_actions(env: TabletopEnv, poses: Poses, actions: np.ndarray, seed: int, settle_steps: int = 5) -> tuple[bool, list]:
    """Replay `actions` open loop from `poses`; success is checked after a short settle."""
    obs = env.reset(poses, seed=seed)
    frames = []
    for action in actions:
        frames.append((obs, action))
        obs = env.step(action)
    for _ in range(settle_steps):  # hold the last command so a just-released object comes to rest
        env.step(actions[-1])
    return bool(env.is_success()), frames


def replay_episode(
    env: TabletopEnv,
    actions: np.ndarray,
    estimate: Poses,
    rng: np.random.Generator,
    max_attempts: int = 8,
    perturb_xy_m: float = 0.01,
    perturb_yaw_rad: float = np.pi,
    seed: int = 0,
    yaw_symmetry: Mapping[str, int] | None = None,
) -> ReplayResult:
    """Up to ``max_attempts`` attempts in all (the first from ``estimate`` itself)."""
    if max_attempts < 1:
        raise ValueError(f"max_attempts must be >= 1, got {max_attempts}")
    poses = dict(estimate)
    for attempt in range(max_attempts):
        if attempt > 0:
            poses = perturb(estimate, rng, perturb_xy_m, perturb_yaw_rad, yaw_symmetry)
        success, frames = run_actions(env, poses, actions, seed=seed + attempt)
        if success:
            break
    return ReplayResult(success=success, attempts=attempt + 1, poses=poses, frames=frames)
