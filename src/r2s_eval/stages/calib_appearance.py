"""Stage: the calibrated sim's light and colours from first frames; writes the calibrated sim's
world parameters, which replay and every sim rollout build their simulation with.

Combines what calibration found (the cameras of ``calib.cameras.use``, the joint offsets and the
commands' latency of ``calib_joints``), fits the light and colours (``r2s_eval.calib.appearance``) and writes::

    {"params": {...WorldParams...}, "cameras": {...the cameras record used, or {"method": "none"}},
     "joints": {...calib_joints' report...}, "appearance": {"fitted": bool, "residual_before": ...,
     "residual_after": ..., ...}}
"""

from __future__ import annotations

import dataclasses

import pandas as pd

from r2s_eval.calib.appearance import calibrate_appearance
from r2s_eval.calib.cameras import camera_params
from r2s_eval.sim import WorldParams, load_world_params
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_json, write_json

READS = ("calib.appearance", "calib.camera", "world")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    cameras = read_json(args.cameras) if args.cameras else {"method": "none", "cameras": {}}
    joints = load_world_params(args.joints)
    params = WorldParams(joint_offset_rad=joints.joint_offset_rad, command_latency_steps=joints.command_latency_steps,
                         **camera_params(cameras))
    fitted, appearance = calibrate_appearance(pd.read_parquet(args.index), args.frames, pd.read_parquet(args.estimates),
                                              args.dataset, cfg["world"], params, cfg["calib.appearance"],
                                              cfg["calib.camera"])
    write_json(args.out, {"params": dataclasses.asdict(fitted), "cameras": cameras,
                          "joints": read_json(args.joints)["joints"], "appearance": appearance}, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--cameras", help="the cameras record used (calib_board's or calib_silhouette's; none: nominal)")
    p.add_argument("--joints", required=True, help="calib_joints' world parameters (the joint offsets)")
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True, help="ingest's episode index")
    p.add_argument("--frames", required=True, help="ingest's first frames folder")
    p.add_argument("--estimates", required=True, help="the initial-pose estimates")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
