"""Stage: fit the per-task pose offsets on the held-out calibration episodes, once.

Estimates the calibration episodes' poses without offsets (through the calibrated cameras), compares them with the measured
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

import pandas as pd

from r2s_eval.calib.cameras import calibrated_cameras
from r2s_eval.calib.episodes import calibrate_offsets
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json

# The pose estimate's settings, not the joints' (calib.joints): those never rerun it.
READS = ("calib.camera", "calib.segmenter", "calib.refine", "calib.calibration.episodes_per_task",
         "world")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    calib = {"camera": cfg["calib.camera"], "segmenter": cfg["calib.segmenter"], "refine": cfg["calib.refine"]}
    result = calibrate_offsets(pd.read_parquet(args.index), args.frames, calib, cfg["world"], args.measured,
                               per_task=int(cfg["calib.calibration.episodes_per_task"]),
                               cameras=calibrated_cameras(args.cameras))
    write_json(args.out, result, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--index", required=True)
    p.add_argument("--frames", required=True)
    p.add_argument("--measured", help="measured poses of (at least) the calibration episodes: parquet or CSV")
    p.add_argument("--cameras", help="the calibrated cameras (calib_board's or calib_silhouette's record); "
                                     "none: the model's")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
