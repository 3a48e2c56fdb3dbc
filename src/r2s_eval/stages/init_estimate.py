"""Stage: estimate every episode's initial object poses from its first head-camera frame.

Runs in the calibrated (nominal) sim: its camera model is the calibration, its renders are
what the refinement matches. It never sees the twin's parameters or true poses. The per-task
offsets come frozen from ``init_offsets`` (fitted on the held-out calibration episodes,
which are flagged ``calibration`` in the output so no score counts them as test data).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import pandas as pd

from r2s_eval.calib.cameras import calibrated_cameras
from r2s_eval.calib.episodes import estimate_episodes
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_parquet

# The pose estimate's settings, not the joints' (calib.joints): those never rerun it.
READS = ("calib.camera", "calib.segmenter", "calib.refine", "world")  # config paths the --cfg slice holds (see _reads.py)

log = logging.getLogger("r2s_eval.init")


def main(args) -> None:
    calib = {"camera": args.cfg["calib.camera"], "segmenter": args.cfg["calib.segmenter"],
             "refine": args.cfg["calib.refine"]}
    world = args.cfg["world"]
    index = pd.read_parquet(args.index)
    fitted = json.loads(Path(args.offsets).read_text())
    started = time.perf_counter()
    table = estimate_episodes(index, args.frames, calib, world, fitted["offsets"], cameras=calibrated_cameras(args.cameras))
    s_per_episode = (time.perf_counter() - started) / max(len(index), 1)
    table["calibration"] = table["episode_index"].isin(fitted["calibration_episodes"])
    log.info("median reprojection error %.2f px over %d objects", table["reproj_error_px"].median(), len(table))
    write_parquet(args.out, table, metadata={"stage": "init_estimate", "camera": calib["camera"],
                                             "s_per_episode": s_per_episode})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--index", required=True)
    p.add_argument("--frames", required=True)
    p.add_argument("--offsets", required=True, help="offsets.json written by init_offsets")
    p.add_argument("--cameras", help="the calibrated cameras (calib_board's or calib_silhouette's record); "
                                     "none: the model's")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
