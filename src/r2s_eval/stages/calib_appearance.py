"""Stage: the calibrated sim's light and colours from first frames; writes the calibrated sim's
world parameters, which replay and every sim rollout build their simulation with.

Combines what calibration found (the cameras of ``calib.cameras.use``, the joint offsets and the
commands' latency of ``calib_joints``, the background plates of ``calib_background`` where
``calib.background.fit``), fits the light and colours (``r2s_eval.calib.appearance``) and writes::

    {"params": {...WorldParams...}, "cameras": {...the cameras record used, or {"method": "none"}},
     "joints": {...calib_joints' report...}, "appearance": {"fitted": bool, "residual_before": ...,
     "residual_after": ..., ...}, "background": {...calib_background's record..., "errors": {camera:
     {"with_plate": ..., "without_plate": ..., "frames": ... [, "shadows": {"pixels", "recorded", "sim",
     "unshaded_recorded", "frames"}]}}} (with plates only; "shadows" with calib.appearance.shadows:
     ``r2s_eval.calib.background.shadow_agreement``)}
"""

from __future__ import annotations

import dataclasses
import logging

import pandas as pd

from r2s_eval.calib.appearance import calibrate_appearance
from r2s_eval.calib.background import plate_errors, shadow_agreement
from r2s_eval.calib.cameras import camera_params
from r2s_eval.sim import WorldParams, load_world_params
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_json, write_json

log = logging.getLogger("r2s_eval.calib_appearance")

READS = ("calib.appearance", "calib.camera", "world")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    cameras = read_json(args.cameras) if args.cameras else {"method": "none", "cameras": {}}
    joints = load_world_params(args.joints)
    background = read_json(f"{args.background}/background.json") if args.background else None
    plates = {} if background is None else {
        "background_plates": background["plates"], "background_states": tuple(map(tuple, background["states"])),
        # a record from before it stated its margin was taken at the default
        "background_margin_px": int(background.get("margin_px", WorldParams.background_margin_px))}
    params = WorldParams(joint_offset_rad=joints.joint_offset_rad, command_latency_steps=joints.command_latency_steps,
                         **plates, **camera_params(cameras))
    index, estimates = pd.read_parquet(args.index), pd.read_parquet(args.estimates)
    fitted, appearance = calibrate_appearance(index, args.frames, estimates, args.dataset, cfg["world"], params,
                                              cfg["calib.appearance"], cfg["calib.camera"])
    record = {"params": dataclasses.asdict(fitted), "cameras": cameras, "joints": read_json(args.joints)["joints"],
              "appearance": appearance}
    if background:
        errors = plate_errors(args.dataset, index, estimates, cfg["world"], fitted, cfg["calib.appearance"])
        for cam, agreement in shadow_agreement(args.dataset, index, estimates, cfg["world"], fitted,
                                               cfg["calib.appearance"]).items():
            errors[cam]["shadows"] = agreement
        record["background"] = {**background, "errors": errors}
        for cam, e in errors.items():
            log.info("%s: first frames' colour error %.1f with its plate, %.1f without (0-255, %d frames)", cam,
                     e["with_plate"], e["without_plate"], e["frames"])
            if (e.get("shadows") or {}).get("pixels"):
                s = e["shadows"]
                log.info("%s: where the sim shades the room (%d px of %d frames) the recordings are at %.2f of the "
                         "plate, the sim at %.2f; elsewhere the recordings at %.2f", cam, s["pixels"], s["frames"],
                         s["recorded"], s["sim"], s["unshaded_recorded"])
    write_json(args.out, record, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--cameras", help="the cameras record used (calib_board's or calib_silhouette's; none: nominal)")
    p.add_argument("--joints", required=True, help="calib_joints' world parameters (the joint offsets)")
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True, help="ingest's episode index")
    p.add_argument("--frames", required=True, help="ingest's first frames folder")
    p.add_argument("--estimates", required=True, help="the initial-pose estimates")
    p.add_argument("--background", help="calib_background's folder (its plates); none: the sim's own surroundings")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
