"""Stage: estimate the robot's joint offsets from its recordings; write the calibrated sim's world.

Replays every ingested episode's recorded actions in the simulation (objects at their estimated
initial poses) and fits, per joint, the offset that makes the simulated joints follow the
recorded ones (``r2s_eval.calib.joints``). Writes the world parameters every calibrated-sim
stage builds its simulation with (replay, sim rollouts)::

    {"params": {...WorldParams: joint_offset_rad estimated, the rest nominal...},
     "joints": {"estimated": bool, "episodes": n, "frames": n, "offsets_rad": {arm: [...]},
                "pass_residual_rad": [{arm: [...]}, ...]}}

With ``calib.joints.estimate: false`` the parameters are nominal (the simulation as built).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pandas as pd

from r2s_eval.calib.joints import estimate_joint_offsets, recorded_episodes
from r2s_eval.sim import WorldParams
from r2s_eval.sim.build import make_env
from r2s_eval.sim.robot import world_robot
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json

READS = ("calib.joints", "world")  # config paths the --cfg slice holds (see _reads.py)

log = logging.getLogger("r2s_eval.calib_joints")


def main(args) -> None:
    joints, world = args.cfg["calib.joints"], args.cfg["world"]
    robot = world_robot(world)
    report: dict = {"estimated": bool(joints["estimate"])}
    params = WorldParams()
    if joints["estimate"]:
        episodes = recorded_episodes(args.dataset, pd.read_parquet(args.index), pd.read_parquet(args.estimates))
        fit = estimate_joint_offsets(robot, episodes, lambda task, p: make_env(task, world, p, cameras=[]),
                                     int(joints["iterations"]))
        params = WorldParams(joint_offset_rad=fit.offsets_rad)
        report.update(episodes=fit.episodes, frames=fit.frames, offsets_rad=fit.offsets_rad,
                      pass_residual_rad=fit.pass_residual_rad)
        for arm, offsets in fit.offsets_rad.items():
            log.info("%s joint offsets (deg): %s; residual left (deg): %s", arm,
                     np.round(np.rad2deg(offsets), 2).tolist(),
                     np.round(np.rad2deg(fit.pass_residual_rad[-1][arm]), 3).tolist())
    else:
        log.info("calib.joints.estimate is false: the calibrated sim keeps the nominal joints")
    write_json(args.out, {"params": dataclasses.asdict(params), "joints": report}, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True, help="ingest's episode index (the episodes to fit on)")
    p.add_argument("--estimates", required=True, help="initial-pose estimates (where the objects start)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
