"""Read a recorded trajectory and measure its motion, pauses, progress and contact forces.

Pure numpy on the per-step arrays; the kinematic judge turns these numbers into sentences.
Only the robot/progress columns are read: the object pose columns are not needed here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from r2s_eval.errors import DataError

_LIST_COLUMNS = ("state", "action")
_EE_PREFIX = "ee_pos_"  # one column per arm: ee_pos_<arm>
_SCALAR_COLUMNS = ("step", "time_s", "contact_force_n", "progress")
DEFAULT_DT_S = 0.1  # the control rate is 10 Hz


@dataclass(frozen=True)
class Trajectory:
    time_s: np.ndarray  # (T,)
    state: np.ndarray  # (T, D) joint positions + gripper openings, the world's dataset layout
    action: np.ndarray  # (T, D) commanded joint targets
    ee: tuple[np.ndarray, ...]  # per arm (T, 3) grasp-centre positions, metres
    force_n: np.ndarray  # (T,) total normal contact force
    progress: np.ndarray  # (T,) staged task progress in [0, 1]

    @property
    def n_steps(self) -> int:
        return len(self.time_s)

    @property
    def dt(self) -> float:
        if self.n_steps < 2:
            return DEFAULT_DT_S
        d = float(np.median(np.diff(self.time_s)))
        return d if d > 0 else DEFAULT_DT_S


def _list_column(table: Any, name: str, path: Path) -> np.ndarray:
    col = table.column(name).combine_chunks()
    n = len(col)
    flat = np.asarray(col.flatten().to_numpy(zero_copy_only=False), dtype=float)
    if n == 0 or flat.size % n:
        raise DataError(f"{path}: column {name!r} rows do not all have the same length")
    return flat.reshape(n, flat.size // n)


def load_trajectory(path: str | Path) -> Trajectory:
    """Load one trajectory parquet; errors name the file and the offending column."""
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trajectory file not found: {path}")
    names = pq.read_schema(path).names
    ee_columns = [c for c in names if c.startswith(_EE_PREFIX)]
    lacking = [c for c in (*_SCALAR_COLUMNS, *_LIST_COLUMNS) if c not in names] + ([] if ee_columns else [f"{_EE_PREFIX}<arm>"])
    if lacking:
        raise DataError(f"{path}: trajectory lacks columns {lacking}")
    list_columns = [*_LIST_COLUMNS, *ee_columns]
    table = pq.read_table(path, columns=[*_SCALAR_COLUMNS, *list_columns])
    if table.num_rows == 0:
        raise DataError(f"{path}: trajectory has no steps")
    # Rows are control steps; sort by step in case a writer appended out of order.
    order = np.argsort(table.column("step").to_numpy(), kind="stable")
    scalar = {c: np.asarray(table.column(c).to_numpy(), dtype=float)[order] for c in _SCALAR_COLUMNS}
    lists = {c: _list_column(table, c, path)[order] for c in list_columns}
    for c, arr in {**scalar, **lists}.items():
        if not np.all(np.isfinite(arr)):
            raise DataError(f"{path}: column {c!r} has NaN or infinite values")
    return Trajectory(
        time_s=scalar["time_s"],
        state=lists["state"],
        action=lists["action"],
        ee=tuple(lists[c] for c in ee_columns),
        force_n=scalar["contact_force_n"],
        progress=np.clip(scalar["progress"], 0.0, 1.0),
    )


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else 0.0


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index ranges where `mask` is True."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def smoothness_metrics(tr: Trajectory, joint_dims: list[int] | None) -> dict[str, float]:
    """Jerk of joints and end effectors (third finite difference) and jitter of the commands."""
    dt = tr.dt
    q = tr.state if joint_dims is None else tr.state[:, joint_dims]
    a = tr.action if joint_dims is None else tr.action[:, joint_dims]
    joint_jerk = np.diff(q, n=3, axis=0) / dt**3
    # Per-arm jerk vector norm, so the value does not depend on how many arms move.
    ee_jerk = np.concatenate(
        [np.linalg.norm(np.diff(p, n=3, axis=0), axis=1) for p in tr.ee]
    ) / dt**3
    # Jitter: step-to-step change of the commanded step, i.e. chattering targets.
    jitter = np.diff(a, n=2, axis=0)
    return {
        "ee_jerk_rms_m_s3": _rms(ee_jerk),
        "ee_jerk_p95_m_s3": float(np.percentile(ee_jerk, 95)) if ee_jerk.size else 0.0,
        "joint_jerk_rms_rad_s3": _rms(np.linalg.norm(joint_jerk, axis=1)) if joint_jerk.size else 0.0,
        "action_jitter_rms_rad": _rms(np.linalg.norm(jitter, axis=1)) if jitter.size else 0.0,
    }


def progress_metrics(tr: Trajectory, success_progress: float, partial_min_progress: float) -> dict[str, Any]:
    """Max/final progress and the outcome label read from the progress signal alone."""
    p = tr.progress
    final, peak = float(p[-1]), float(p.max())
    if final >= success_progress - 1e-9:
        label = "successful"
    elif peak >= partial_min_progress:
        label = "partially successful"
    else:
        label = "failed"
    reached = np.flatnonzero(p >= success_progress - 1e-9)
    peak_at = int(np.flatnonzero(p >= peak - 1e-9)[0])
    return {
        "max_progress": peak,
        "final_progress": final,
        "progress_lost": peak - final,
        "time_to_max_progress_s": float(tr.time_s[peak_at] - tr.time_s[0]),
        "time_to_success_s": float(tr.time_s[reached[0]] - tr.time_s[0]) if reached.size else None,
        "duration_s": float(tr.time_s[-1] - tr.time_s[0]) if tr.n_steps > 1 else 0.0,
        "label": label,
    }


def continuity_metrics(
    tr: Trajectory,
    joint_dims: list[int] | None,
    idle_speed_rad_s: float,
    min_pause_steps: int,
    reversal_min_speed_m_s: float,
    success_progress: float,
) -> dict[str, float]:
    """Hesitations mid-task: idle steps, stop-and-go pauses and end-effector direction reversals.

    "Mid-task" runs from the first moving step until the task is done (progress first reaches
    `success_progress`) or the episode ends; resting after success is not hesitation.
    """
    dt = tr.dt
    q = tr.state if joint_dims is None else tr.state[:, joint_dims]
    speed = np.linalg.norm(np.diff(q, axis=0), axis=1) / dt  # (T-1,) joint-space speed per step
    moving = speed >= idle_speed_rad_s
    done = np.flatnonzero(tr.progress[1:] >= success_progress - 1e-9)
    end = int(done[0]) if done.size else len(speed)
    first = np.flatnonzero(moving[:end])
    start = int(first[0]) if first.size else 0
    window = ~moving[start:end]
    idle_runs = _runs(window)
    # A pause is an idle run long enough to be a stop that is followed by motion again (stop-and-go);
    # an idle run that lasts to the end of the window is a stall, counted in idle_fraction instead.
    pauses = sum(1 for s, e in idle_runs if e - s >= min_pause_steps and e < len(window))
    longest = max((e - s for s, e in idle_runs), default=0)
    reversals = 0
    for p in tr.ee:
        v = np.diff(p, axis=0)[start:end] / dt
        fast = np.linalg.norm(v, axis=1) >= reversal_min_speed_m_s
        both = fast[:-1] & fast[1:]
        reversals += int(np.sum((np.einsum("ij,ij->i", v[:-1], v[1:]) < 0) & both))
    window_s = max(len(window) * dt, dt)
    return {
        "idle_fraction": float(window.mean()) if window.size else (0.0 if moving.any() else 1.0),
        "idle_steps": int(window.sum()),
        "longest_idle_s": float(longest * dt),
        "pauses": int(pauses),
        "pauses_per_10s": float(pauses / window_s * 10.0),
        "reversals": int(reversals),
        "reversals_per_s": float(reversals / window_s),
    }


def force_metrics(tr: Trajectory, contact_threshold_n: float, impact_jump_n: float) -> dict[str, float]:
    """Peak and mean (while in contact) normal force, and impacts (force jumps within one step)."""
    f = tr.force_n
    contact = f > contact_threshold_n
    jumps = np.diff(f)
    return {
        "peak_force_n": float(f.max()),
        "mean_contact_force_n": float(f[contact].mean()) if contact.any() else 0.0,
        "contact_fraction": float(contact.mean()),
        "impacts": int(np.sum(jumps > impact_jump_n)),
        "max_force_rise_n_per_step": float(jumps.max()) if jumps.size else 0.0,
    }
