"""Replay a whole teleop dataset in the calibrated sim: one environment per task, each episode
from its initial-pose estimate with its own seeded retries, the successes recorded as a LeRobot
dataset and every episode as a row of the replay log."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.data import ACTION_KEY, DatasetRecorder, episode_frames, lerobot_features, open_metadata
from r2s_eval.errors import DataError
from r2s_eval.replay import replay_episode
from r2s_eval.sim import WorldParams
from r2s_eval.sim.build import make_env
from r2s_eval.sim.robot import world_robot

log = logging.getLogger("r2s_eval.replay")


def replay_dataset(dataset: str | Path, index: pd.DataFrame, estimates: pd.DataFrame, params: WorldParams,
                   out_dataset: str | Path, *, world: dict, video: bool, max_attempts: int, perturb_xy_m: float,
                   perturb_yaw_rad: float, seed: int) -> pd.DataFrame:
    """Replay every episode of ``index`` (rows in its order) and return the replay log: per episode
    its success, attempts, index in ``out_dataset`` (-1 when it failed), whether it is a calibration
    episode, its wall time and the initial poses of its last attempt.

    Episode ``e``'s retries draw from ``np.random.default_rng([seed, e])``: an episode replays the
    same whichever other episodes run with it.
    """
    meta = open_metadata(dataset)
    features = lerobot_features(
        meta.features["observation.state"]["names"], meta.features[ACTION_KEY]["names"], world["cameras"],
        (world["image_height"], world["image_width"]),
    )
    envs, rows = {}, []
    robot = world_robot(world)
    with DatasetRecorder(out_dataset, "local/replay", round(robot.control_hz), features, f"{robot.type}_sim",
                         video=video) as rec:
        for ep in tqdm(index.itertuples(), total=len(index), desc="replay", mininterval=5):
            if ep.task not in envs:
                envs[ep.task] = make_env(ep.task, world, params)
            env = envs[ep.task]
            est = estimates[estimates["episode_index"] == ep.episode_index]
            if est.empty:
                raise DataError(f"episode {ep.episode_index}: no initial-pose estimate")
            poses = {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in est.itertuples()}
            symmetry = {r.object: int(r.yaw_symmetry) for r in est.itertuples()}
            actions = np.stack(episode_frames(dataset, meta, ep.episode_index)[ACTION_KEY].to_numpy())
            if actions.shape[1] != robot.action_dim:
                raise DataError(f"episode {ep.episode_index}: actions have {actions.shape[1]} dims, the world's robot "
                                f"takes {robot.action_dim}")
            started = time.perf_counter()
            rng = np.random.default_rng([seed, int(ep.episode_index)])
            result = replay_episode(env, actions, poses, rng, seed=int(ep.episode_index), yaw_symmetry=symmetry,
                                    max_attempts=max_attempts, perturb_xy_m=perturb_xy_m,
                                    perturb_yaw_rad=perturb_yaw_rad)
            sim_index = rec.submit_episode(result.frames, ep.instruction) if result.success else -1
            row = {"episode_index": int(ep.episode_index), "task": ep.task, "success": result.success,
                   "attempts": result.attempts, "sim_episode_index": sim_index,
                   "calibration": bool(est["calibration"].iloc[0]) if "calibration" in est else False,
                   "wall_s": time.perf_counter() - started}
            for name, (x, y, yaw) in result.poses.items():
                row.update({f"{name}.x_m": x, f"{name}.y_m": y, f"{name}.yaw_rad": yaw})
            rows.append(row)
            log.info("episode %d: %s after %d attempt(s)", ep.episode_index, "success" if result.success else "FAILED", result.attempts)
    return pd.DataFrame(rows)
