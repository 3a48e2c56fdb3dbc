"""Per-task pose offsets, fitted once on a held-out calibration subset of episodes, then frozen.

What the image-based estimate cannot see is a systematic error: the real camera sits a few
millimetres and a fraction of a degree away from its calibration, so every object of a task
is estimated shifted by about the same planar offset. The offsets are fitted on a few
*calibration episodes* per task whose object poses were measured (on a robot: by hand, with
a ruler or a tracker; in the reality twin: its logged true poses of those episodes only) and
then added to every other estimate. Calibration episodes are never scored as test data.

Offsets: ``{task: {object: [dx_m, dy_m, dyaw_rad]}}`` with ``true = estimate + offset``;
the position offsets are medians (robust to one bad frame), the yaw offset is the circular
mean of the differences modulo the object's symmetry (0 for rotationally symmetric objects).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.calib.estimate import wrap_yaw
from r2s_eval.errors import ConfigError, DataError


def calibration_subset(index: pd.DataFrame, per_task: int) -> pd.DataFrame:
    """The first ``per_task`` episodes (by episode index) of each task: the held-out calibration set."""
    if per_task < 0:
        raise ConfigError(f"calibration episodes per task must be >= 0, got {per_task}")
    ordered = index.sort_values("episode_index")
    subset = ordered.groupby("task", sort=True).head(per_task)
    for task, n in ordered.groupby("task").size().items():
        if per_task and n <= per_task:
            raise DataError(
                f"task {task!r} has {n} episode(s): holding out {per_task} for calibration leaves none to score"
            )
    return subset


def _circular_mean(angles_rad: np.ndarray, symmetry: int) -> float:
    """Mean of angles that are only defined modulo 2*pi/symmetry."""
    if symmetry == 0 or len(angles_rad) == 0:
        return 0.0
    z = np.exp(1j * symmetry * np.asarray(angles_rad))
    return wrap_yaw(float(np.angle(z.mean())) / symmetry, symmetry)


def fit_offsets(estimates: pd.DataFrame, measured: pd.DataFrame) -> dict[str, dict[str, list[float]]]:
    """Offsets per (task, object) from raw estimates and measured poses of the same episodes.

    Both tables have columns episode_index, object, x_m, y_m, yaw_rad; ``estimates`` also
    task and yaw_symmetry. Every estimated (episode, object) needs a measurement.
    """
    merged = estimates.merge(measured[["episode_index", "object", "x_m", "y_m", "yaw_rad"]],
                             on=["episode_index", "object"], suffixes=("_est", "_true"), how="left")
    missing = merged[merged["x_m_true"].isna()]
    if len(missing):
        pairs = sorted(zip(missing["episode_index"], missing["object"]))[:5]
        raise DataError(f"calibration episodes without a measured pose (episode, object): {pairs}")
    offsets: dict[str, dict[str, list[float]]] = {}
    for (task, obj), g in merged.groupby(["task", "object"], sort=True):
        symmetry = int(g["yaw_symmetry"].iloc[0])
        dyaw = [wrap_yaw(t - e, symmetry) if symmetry else 0.0 for e, t in zip(g["yaw_rad_est"], g["yaw_rad_true"])]
        offsets.setdefault(task, {})[obj] = [
            float(np.median(g["x_m_true"] - g["x_m_est"])),
            float(np.median(g["y_m_true"] - g["y_m_est"])),
            _circular_mean(np.array(dyaw), symmetry),
        ]
    return offsets


def read_measured_poses(path: str, episodes: list[int]) -> pd.DataFrame:
    """Measured poses (parquet or CSV: episode_index, object, x_m, y_m, yaw_rad) of `episodes` only."""
    table = pd.read_parquet(path) if path.endswith(".parquet") else pd.read_csv(path)
    missing = {"episode_index", "object", "x_m", "y_m", "yaw_rad"} - set(table.columns)
    if missing:
        raise DataError(f"{path}: measured poses lack columns {sorted(missing)}")
    # Only the calibration episodes' measurements are read: the rest is test data.
    columns = ["episode_index", "object", "x_m", "y_m", "yaw_rad"]
    return table.loc[table["episode_index"].isin(episodes), columns].reset_index(drop=True)


def median_error_mm(estimates: pd.DataFrame, measured: pd.DataFrame, offsets: dict | None) -> dict:
    """Median planar error (mm) per task and object, after adding `offsets` to the estimates."""
    merged = estimates.merge(measured, on=["episode_index", "object"], suffixes=("_est", "_true"))
    out = {}
    for (task, obj), g in merged.groupby(["task", "object"]):
        dx, dy, _ = (offsets or {}).get(task, {}).get(obj, [0.0, 0.0, 0.0])
        err = 1000 * np.hypot(g["x_m_est"] + dx - g["x_m_true"], g["y_m_est"] + dy - g["y_m_true"])
        out.setdefault(task, {})[obj] = float(np.median(err))
    return out
