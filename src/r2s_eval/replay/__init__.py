"""Automatic action replay: re-run recorded joint actions in the calibrated simulation.

The first attempt starts from the estimated initial poses; while the task's success check
fails, retry from poses perturbed around the estimate (within +-perturb_xy_m in x and y;
yaw within +-perturb_yaw_rad for objects whose yaw is observable, anywhere on a full turn for
rotationally symmetric ones, whose yaw the estimate cannot know), up to ``max_attempts``
attempts in all. The first successful attempt's observations, paired with the recorded
actions, become a simulated demonstration.

The retries' offsets are a scrambled Sobol' design over every object's (x, y, yaw), seeded per
episode: a handful of independent draws clumps and leaves parts of the window untried, while
8 Sobol' points put one retry in each eighth of every axis.

``r2s_eval.replay.dataset_replay.replay_dataset`` replays a whole teleop dataset this way (the replay stage).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import qmc

from r2s_eval.errors import ConfigError
from r2s_eval.sim import TabletopEnv

Poses = dict[str, tuple[float, float, float]]


@dataclass
class ReplayResult:
    success: bool
    attempts: int  # attempts run, the first (unperturbed) one included
    poses: Poses  # initial poses of the last attempt
    frames: list[tuple[dict, np.ndarray]] = field(repr=False)  # (observation, action) of the last attempt


def retry_design(n_retries: int, n_objects: int, rng: np.random.Generator) -> np.ndarray:
    """Offsets in [-1, 1) for ``n_retries`` retries, shape (n_retries, n_objects, 3): the first
    points of a scrambled Sobol' sequence over every object's (x, y, yaw)."""
    if n_retries <= 0:
        return np.zeros((0, n_objects, 3))
    sobol = qmc.Sobol(d=3 * n_objects, scramble=True, rng=rng)
    # A power-of-two block keeps the design balanced; the first n_retries of it are used.
    points = sobol.random_base2(int(np.ceil(np.log2(n_retries))))[:n_retries]
    return (2.0 * points - 1.0).reshape(n_retries, n_objects, 3)


def perturb(poses: Poses, offsets: np.ndarray, xy_m: float, yaw_rad: float,
            yaw_symmetry: Mapping[str, int] | None = None) -> Poses:
    """Poses shifted by ``offsets`` (one row of `retry_design` per object, in the order of
    ``poses``) scaled to +-xy_m and +-yaw_rad; a symmetric object's yaw spans a full turn.

    Objects missing from ``yaw_symmetry`` count as having an observable yaw.
    """
    out = {}
    for (name, (x, y, yaw)), (dx, dy, dyaw) in zip(poses.items(), offsets, strict=True):
        symmetric = yaw_symmetry is not None and yaw_symmetry.get(name, 1) == 0
        new_yaw = float(np.pi * dyaw) if symmetric else yaw + yaw_rad * float(dyaw)
        out[name] = (x + xy_m * float(dx), y + xy_m * float(dy), new_yaw)
    return out


def run_actions(env: TabletopEnv, poses: Poses, actions: np.ndarray, seed: int, settle_s: float = 0.5) -> tuple[bool, list]:
    """Replay `actions` open loop from `poses` (the recording's own length); success is checked
    after a short settle (a time: 5 steps at 10 Hz, 15 at 30 Hz)."""
    obs = env.reset(poses, seed=seed)
    frames = []
    for action in actions:
        frames.append((obs, action))
        obs = env.step(action)
    for _ in range(env.robot.steps_in(settle_s)):  # hold the last command so a just-released object comes to rest
        env.step(actions[-1])
    return bool(env.is_success()), frames


def replay_episode(
    env: TabletopEnv,
    actions: np.ndarray,
    estimate: Poses,
    rng: np.random.Generator,
    *,
    max_attempts: int,
    perturb_xy_m: float,
    perturb_yaw_rad: float,
    seed: int = 0,
    yaw_symmetry: Mapping[str, int] | None = None,
) -> ReplayResult:
    """Up to ``max_attempts`` attempts in all (the first from ``estimate`` itself). The retry
    window has no default: it is the config's (`conf/replay`), whose default is not the method's."""
    if max_attempts < 1:
        raise ConfigError(f"replay.max_attempts must be >= 1, got {max_attempts}")
    poses = dict(estimate)
    design = retry_design(max_attempts - 1, len(estimate), rng)
    for attempt in range(max_attempts):
        if attempt > 0:
            poses = perturb(estimate, design[attempt - 1], perturb_xy_m, perturb_yaw_rad, yaw_symmetry)
        success, frames = run_actions(env, poses, actions, seed=seed + attempt)
        if success:
            break
    return ReplayResult(success=success, attempts=attempt + 1, poses=poses, frames=frames)
