"""Stage: replay every teleop episode in the calibrated sim (``--world-params``) and record the successes."""

from __future__ import annotations

import logging

import pandas as pd

from r2s_eval.replay.dataset_replay import replay_dataset
from r2s_eval.sim import load_world_params
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_parquet

READS = ("replay.video", "replay.max_attempts", "replay.perturb_xy_m", "replay.perturb_yaw_rad", "world",
         "seed")  # config paths the --cfg slice holds (see _reads.py)

log = logging.getLogger("r2s_eval.replay")


def main(args) -> None:
    cfg = args.cfg
    table = replay_dataset(
        args.dataset, pd.read_parquet(args.index), pd.read_parquet(args.estimates),
        load_world_params(args.world_params), args.out_dataset, world=cfg["world"], video=cfg["replay.video"],
        max_attempts=cfg["replay.max_attempts"], perturb_xy_m=cfg["replay.perturb_xy_m"],
        perturb_yaw_rad=cfg["replay.perturb_yaw_rad"], seed=cfg["seed"],
    )
    log.info("replay success %.1f%% (%d/%d)", 100 * table["success"].mean(), table["success"].sum(), len(table))
    write_parquet(args.out_log, table, metadata={"stage": "replay"})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True)
    p.add_argument("--estimates", required=True)
    p.add_argument("--world-params", required=True, help="the calibrated sim's world parameters (calib_joints)")
    p.add_argument("--out-dataset", required=True)
    p.add_argument("--out-log", required=True)
    _cli.run(main, p)
