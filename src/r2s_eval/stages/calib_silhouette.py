"""Stage: the fixed cameras' poses from the robot's silhouette in the teleop recordings
(``r2s_eval.calib.silhouette``); no board needed.

Writes the same record as ``calib_board`` (``"method": "silhouette"``), with each camera's
silhouette mismatch and the frames used, and the cameras it skipped (on an arm) with why.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.calib.cameras import camera_params
from r2s_eval.calib.silhouette import calibrate_from_silhouette
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_json, write_json

READS = ("calib.cameras.silhouette", "calib.segmenter", "world", "tasks")  # see _reads.py


def main(args) -> None:
    cfg = args.cfg
    episodes = [int(e) for e in pd.read_parquet(args.index)["episode_index"]]
    lenses = camera_params(read_json(args.lenses))["lens_distortion"] if args.lenses else None
    write_json(args.out, calibrate_from_silhouette(args.dataset, episodes, cfg["world"], cfg["calib.cameras.silhouette"],
                                                   cfg["calib.segmenter"], cfg["tasks"], lenses), provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True, help="ingest's episode index (the episodes to fit on)")
    p.add_argument("--lenses", help="a cameras record whose fitted lenses the frames are undistorted through "
                                    "(calib_board's with calib.cameras.board.intrinsics); none: pinholes")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
