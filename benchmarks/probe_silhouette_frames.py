"""How many frames, and which arm poses, pin a camera down by the robot's silhouette?

In a finished twin run's folder, fits every recorded fixed camera from the robot's silhouette in
the teleop recording (``r2s_eval.calib.silhouette``, the run's config otherwise) with several
frame counts, picking either the most different arm poses among every 5th frame (what the stage
does) or only each episode's first frame (the arm at home in all of them), and prints each
camera's error against the twin's true pose and the silhouette mismatch left.

Run::

    python benchmarks/probe_silhouette_frames.py [--experiment demo] [--frames 8 16 32 48 96]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import pandas as pd  # noqa: E402

from r2s_eval.calib.cameras import camera_errors, camera_params  # noqa: E402
from r2s_eval.calib.silhouette import calibrate_from_silhouette  # noqa: E402
from r2s_eval.config import compose_config  # noqa: E402
from r2s_eval.paths import CONF_DIR  # noqa: E402
from r2s_eval.sim import WorldParams, load_world_params  # noqa: E402

PICKS = {"varied poses": 5, "first frames (home)": 10**6}  # the stride between candidate frames


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--run", default=".", help="a finished twin run's working directory")
    p.add_argument("--experiment", default="demo")
    p.add_argument("--overrides", nargs="*", default=[], help="Hydra overrides the run was made with")
    p.add_argument("--frames", nargs="+", type=int, default=[8, 16, 32, 48, 96])
    args = p.parse_args()
    run = Path(args.run)
    cfg = compose_config(CONF_DIR, args.experiment, args.overrides)
    world, silhouette = cfg["world"], dict(cfg["calib"]["cameras"]["silhouette"], min_frames=1, max_mismatch=1.0)
    episodes = [int(e) for e in pd.read_parquet(run / "results/ingest/episodes.parquet")["episode_index"]]
    truth = load_world_params(run / "results/real/twin_params.json")
    print(f"{'frames':>6} {'picked':22s} {'camera':12s} {'error mm':>9} {'deg':>6} {'mismatch':>9} {'s':>5}")
    for label, stride in PICKS.items():
        for n in args.frames:
            started = time.perf_counter()
            record = calibrate_from_silhouette(str(run / "results/real/dataset"), episodes, world,
                                               dict(silhouette, frames=n, stride=stride), cfg["calib"]["segmenter"],
                                               cfg["tasks"])
            seconds = time.perf_counter() - started
            errors = camera_errors(WorldParams(**camera_params(record)), truth, world, cfg["tasks"],
                                   list(record["cameras"]))
            for cam, e in errors.items():
                fit = record["cameras"][cam]
                print(f"{record['frames']:6d} {label:22s} {cam:12s} {e['position_mm']:9.2f} {e['rotation_deg']:6.3f} "
                      f"{fit['mismatch']:9.3f} {seconds:5.0f}", flush=True)
            if stride > 5 and record["frames"] < n:
                break  # every first frame is in already


if __name__ == "__main__":
    main()
