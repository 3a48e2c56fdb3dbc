"""Stage: a background plate per fixed camera from the teleop recordings, seen through the
calibrated cameras (``r2s_eval.calib.background``); the calibrated sim draws its robot and task
objects over them (``calib_appearance`` puts them in its world parameters).

Writes ``<out>/<camera>.png`` and ``<out>/background.json``: ``{"plates": {camera: path}, "frames":
..., "cameras": {camera: {"frames_used", "free_frames_median", "free_frames_min", "unseen_share", "inpainted_share"}},
"skipped": {camera: why}, "states": the robot's recorded state at each frame used}``.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.calib.background import fit_plates, write_plates
from r2s_eval.calib.cameras import calibrated_cameras
from r2s_eval.stages import _cli
from r2s_eval.utils.io import atomic_dir, write_json

READS = ("calib.background", "world")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    estimates = pd.read_parquet(args.estimates) if args.estimates else None
    plates, record = fit_plates(args.dataset, pd.read_parquet(args.index), estimates, cfg["world"],
                                calibrated_cameras(args.cameras), cfg["calib.background"])
    with atomic_dir(args.out) as tmp:
        written = write_plates(plates, tmp)
        paths = {cam: f"{args.out}/{cam}.png" for cam in written}
        write_json(f"{tmp}/background.json", {"plates": paths, **record}, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True, help="ingest's episode index (the episodes to take the plates from)")
    p.add_argument("--cameras", help="the calibrated cameras (calib_board's or calib_silhouette's record); none: "
                                     "the model's")
    p.add_argument("--estimates", help="the initial-pose estimates (the objects where each episode starts are not "
                                       "room either)")
    p.add_argument("--out", required=True, help="the plates' folder")
    _cli.run(main, p)
