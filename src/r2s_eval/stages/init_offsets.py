"""Stage: fit the per-task pose offsets on the held-out calibration episodes, once.

Estimates the calibration episodes' poses without offsets, compares them with the measured
poses of those episodes only (``--measured``: the reality twin's logged truth, or your CSV of
hand-measured poses with columns episode_index, object, x_m, y_m, yaw_rad), and writes
``offsets.json``::

    {"offsets": {task: {object: [dx_m, dy_m, dyaw_rad]}},
     "calibration_episodes": [episode_index, ...],
     "episodes_per_task": n, "fitted": bool,
     "calibration_error": {task: {object: {"xy_mm_median_before": .., "xy_mm_median_after": ..}}}}

Without measured poses (or with 0 calibration episodes) the offsets are zero and
``fitted`` is false.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from r2s_eval.calib import calibration_subset, fit_offsets, median_error_mm, read_measured_poses
from r2s_eval.stages import _cli
from r2s_eval.calib.episodes import estimate_episodes
from r2s_eval.utils.io import write_json

# The pose estimate's settings, not the joints' (calib.joints): those never rerun it.
READS = ("calib.camera", "calib.segmenter", "calib.refine", "calib.calibration", "world")  # config paths the --cfg slice holds (see _reads.py)

log = logging.getLogger("r2s_eval.init_offsets")


def main(args) -> None:
    calib = {"camera": args.cfg["calib.camera"], "segmenter": args.cfg["calib.segmenter"],
             "refine": args.cfg["calib.refine"], "calibration": args.cfg["calib.calibration"]}
    world = args.cfg["world"]
    per_task = int(calib["calibration"]["episodes_per_task"])
    index = pd.read_parquet(args.index)
    subset = calibration_subset(index, per_task)
    episodes = [int(e) for e in subset["episode_index"]]
    result = {"offsets": {}, "calibration_episodes": episodes, "episodes_per_task": per_task,
              "fitted": False, "calibration_error": {}}
    if args.measured and episodes:
        raw = estimate_episodes(subset, args.frames, calib, world, offsets=None, desc="init_offsets")
        measured = read_measured_poses(args.measured, episodes)
        offsets = fit_offsets(raw, measured)
        before, after = median_error_mm(raw, measured, None), median_error_mm(raw, measured, offsets)
        result.update(offsets=offsets, fitted=True, calibration_error={
            task: {obj: {"xy_mm_median_before": before[task][obj], "xy_mm_median_after": after[task][obj]}
                   for obj in before[task]} for task in before})
        for task, objs in offsets.items():
            for obj, (dx, dy, dyaw) in objs.items():
                log.info("%s/%s: offset (%.1f mm, %.1f mm, %.2f deg); calibration error %.1f -> %.1f mm", task, obj,
                         1000 * dx, 1000 * dy, np.rad2deg(dyaw), before[task][obj], after[task][obj])
    else:
        log.warning("no measured poses for the calibration episodes: offsets are zero")
    write_json(args.out, result, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--index", required=True)
    p.add_argument("--frames", required=True)
    p.add_argument("--measured", help="measured poses of (at least) the calibration episodes: parquet or CSV")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
