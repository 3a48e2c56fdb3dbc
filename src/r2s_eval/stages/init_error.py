"""Stage: score the initial-pose estimates against the reality twin's recorded truth.

Besides the offset fit (which reads the truth of the held-out calibration episodes only),
this is the only reader of the truth file; nothing downstream consumes its output. The
calibration episodes are left out of the scores.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.calib import yaw_error_rad
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json, write_parquet
from r2s_eval.errors import DataError

READS = ()  # config paths the --cfg slice holds (see _reads.py)


def score(estimates: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
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


def main(args) -> None:
    errors = scored_errors(pd.read_parquet(args.estimates), pd.read_parquet(args.truth))
    write_parquet(args.table, errors)
    write_json(args.summary, {"tasks": summarise(errors)}, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__, cfg=False)
    p.add_argument("--estimates", required=True)
    p.add_argument("--truth", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--summary", required=True)
    _cli.run(main, p)
