"""Stage: estimate the robot's joint offsets and its commands' latency from its recordings.

Replays every ingested episode's recorded actions in the simulation (objects at their estimated
initial poses), reads the commands' latency off the lag between the recorded and the replayed
joints, and fits, per joint, the offset that makes the simulated joints follow the recorded ones
(``r2s_eval.calib.joints``). Writes world parameters holding them (calib_appearance adds the
cameras and the appearance to them for the calibrated sim)::

    {"params": {...WorldParams: joint_offset_rad and command_latency_steps estimated, the rest nominal...},
     "joints": {"estimated": bool, "episodes": n, "frames": n, "offsets_rad": {arm: [...]},
                "pass_residual_rad": [{arm: [...]}, ...],
                "latency_steps": k, "latency": {"lags_steps": [0, ...],
                "rms_velocity_residual_deg_per_step": [...], "moving_joints": n, "frames": n}}}

With ``calib.joints.estimate: false`` the joint offsets are nominal, with ``calib.joints.latency:
false`` the commands act at once (no latency keys); with both false the parameters are nominal.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.calib.joints import calibrate_joints
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json

READS = ("calib.joints.estimate", "calib.joints.iterations", "calib.joints.latency", "calib.joints.max_latency_steps",
         "world")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    result = calibrate_joints(args.dataset, pd.read_parquet(args.index), pd.read_parquet(args.estimates), cfg["world"],
                              estimate=cfg["calib.joints.estimate"], iterations=cfg["calib.joints.iterations"],
                              latency=cfg["calib.joints.latency"],
                              max_latency_steps=cfg["calib.joints.max_latency_steps"])
    write_json(args.out, result, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True, help="ingest's episode index (the episodes to fit on)")
    p.add_argument("--estimates", required=True, help="initial-pose estimates (where the objects start)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
