"""Initial-pose estimates scored against the recorded truth (the reality twin's logged poses).

The held-out calibration episodes (the offset fit's) are left out of the scores.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.calib.estimate import yaw_error_rad
from r2s_eval.errors import DataError


def score(estimates: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """Each estimate beside its true pose, with its planar error (mm) and yaw error (deg, modulo
    the object's symmetry); every (episode, object) estimated must have a true pose."""
    merged = estimates.merge(truth, on=["episode_index", "object"], suffixes=("_est", "_true"), validate="one_to_one")
    if len(merged) != len(estimates):
        missing = set(zip(estimates["episode_index"], estimates["object"])) - set(zip(merged["episode_index"], merged["object"]))
        raise DataError(f"no true pose for (episode, object) {sorted(missing)[:5]}")
    merged["error_xy_mm"] = 1000.0 * np.hypot(merged["x_m_est"] - merged["x_m_true"], merged["y_m_est"] - merged["y_m_true"])
    merged["error_yaw_deg"] = [
        np.rad2deg(yaw_error_rad(e, t, int(s)))
        for e, t, s in zip(merged["yaw_rad_est"], merged["yaw_rad_true"], merged["yaw_symmetry"])
    ]
    return merged


def summarise(errors: pd.DataFrame) -> dict:
    """{task: {object: episodes, median and 95th percentile of the xy and yaw errors, symmetry}}."""
    out = {}
    for (task, obj), group in errors.groupby(["task", "object"]):
        out.setdefault(task, {})[obj] = {
            "episodes": int(len(group)),
            "xy_mm_median": float(group["error_xy_mm"].median()),
            "xy_mm_p95": float(group["error_xy_mm"].quantile(0.95)),
            "yaw_deg_median": float(group["error_yaw_deg"].median()),
            "yaw_deg_p95": float(group["error_yaw_deg"].quantile(0.95)),
            "yaw_symmetry": int(group["yaw_symmetry"].iloc[0]),
        }
    return out


def scored_errors(estimates: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """The errors of the test episodes' estimates against the twin's truth."""
    if "calibration" in estimates:  # held out for the offset fit: never scored as test data
        estimates = estimates[~estimates["calibration"]].drop(columns="calibration")
    return score(estimates, truth[["episode_index", "object", "x_m", "y_m", "yaw_rad"]])


def score_estimates(estimates: pd.DataFrame, truth: pd.DataFrame) -> tuple[pd.DataFrame, dict]:
    """The test episodes' errors (`scored_errors`) and their summary ``{"tasks": summarise(...)}``."""
    errors = scored_errors(estimates, truth)
    return errors, {"tasks": summarise(errors)}
