"""Stage: replay every teleop episode in the calibrated sim (``--world-params``) and record the successes."""

from __future__ import annotations

import logging
import time

import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.data import ACTION_KEY, DatasetRecorder, episode_frames, lerobot_features, open_metadata
from r2s_eval.replay import replay_episode
from r2s_eval.sim import load_world_params
from r2s_eval.sim.robot import world_robot
from r2s_eval.stages import _cli
from r2s_eval.sim.build import make_env
from r2s_eval.utils.io import write_parquet
from r2s_eval.errors import DataError

READS = ("replay", "world", "seed")  # config paths the --cfg slice holds (see _reads.py)

log = logging.getLogger("r2s_eval.replay")


def main(args) -> None:
    cfg = args.cfg
    replay, world = cfg["replay"], cfg["world"]
    index = pd.read_parquet(args.index)
    estimates = pd.read_parquet(args.estimates)
    meta = open_metadata(args.dataset)
    features = lerobot_features(
        meta.features["observation.state"]["names"], meta.features[ACTION_KEY]["names"], world["cameras"],
        (world["image_height"], world["image_width"]),
    )
    params, envs, rows = load_world_params(args.world_params), {}, []
    robot = world_robot(world)
    with DatasetRecorder(args.out_dataset, "local/replay", round(robot.control_hz), features, f"{robot.type}_sim",
                         video=replay["video"]) as rec:
        for ep in tqdm(index.itertuples(), total=len(index), desc="replay", mininterval=5):
            if ep.task not in envs:
                envs[ep.task] = make_env(ep.task, world, params)
            env = envs[ep.task]
            est = estimates[estimates["episode_index"] == ep.episode_index]
            if est.empty:
                raise DataError(f"episode {ep.episode_index}: no initial-pose estimate")
            poses = {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in est.itertuples()}
            symmetry = {r.object: int(r.yaw_symmetry) for r in est.itertuples()}
            actions = np.stack(episode_frames(args.dataset, meta, ep.episode_index)[ACTION_KEY].to_numpy())
            if actions.shape[1] != robot.action_dim:
                raise DataError(f"episode {ep.episode_index}: actions have {actions.shape[1]} dims, the world's robot "
                                f"takes {robot.action_dim}")
            started = time.perf_counter()
            rng = np.random.default_rng([cfg["seed"], int(ep.episode_index)])
            window = {k: replay[k] for k in ("max_attempts", "perturb_xy_m", "perturb_yaw_rad")}
            result = replay_episode(env, actions, poses, rng, seed=int(ep.episode_index), yaw_symmetry=symmetry, **window)
            sim_index = rec.submit_episode(result.frames, ep.instruction) if result.success else -1
            row = {"episode_index": int(ep.episode_index), "task": ep.task, "success": result.success,
                   "attempts": result.attempts, "sim_episode_index": sim_index,
                   "calibration": bool(est["calibration"].iloc[0]) if "calibration" in est else False,
                   "wall_s": time.perf_counter() - started}
            for name, (x, y, yaw) in result.poses.items():
                row.update({f"{name}.x_m": x, f"{name}.y_m": y, f"{name}.yaw_rad": yaw})
            rows.append(row)
            log.info("episode %d: %s after %d attempt(s)", ep.episode_index, "success" if result.success else "FAILED", result.attempts)
    table = pd.DataFrame(rows)
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
