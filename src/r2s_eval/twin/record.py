"""The teleop dataset recorded in the reality twin, and the twin's true initial poses.

Operators keep the demonstrations that succeed (as a lab discards botched takes); every
attempt is logged, a failed one with the operator's phase and reason (``r2s_eval.twin.failures``).
The true initial poses (read off the twin, as a person measuring the
scene would) are kept apart from the dataset: they only score the initial-pose estimates
and fit the offsets on the held-out calibration episodes.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.data import DatasetRecorder, lerobot_features
from r2s_eval.errors import R2SError
from r2s_eval.sim import TabletopEnv, WorldParams
from r2s_eval.sim.build import image_size
from r2s_eval.sim.robot import world_robot
from r2s_eval.twin.failures import summary
from r2s_eval.twin.operator import OperatorConfig, make_operator, run_episode
from r2s_eval.twin.reality import RealityEffects, make_reality_env

log = logging.getLogger("r2s_eval.teleop")


def truth_rows(episode_index: int, task: str, env: TabletopEnv, initial: dict) -> list[dict]:
    """One row per object: its true initial planar pose (``initial``: ``env.object_poses()``
    right after the reset) and its yaw symmetry."""
    rows = []
    for name, pose in initial.items():
        x, y, yaw = pose["planar"]  # the convention of reset() and of the estimates
        rows.append({"episode_index": episode_index, "task": task, "object": name, "x_m": float(x), "y_m": float(y),
                     "yaw_rad": float(yaw), "yaw_symmetry": env.task.yaw_symmetry(name)})
    return rows


def record_teleop(dataset: str, params: WorldParams, *, teleop: dict, world: dict, tasks: list[str],
                  suite: dict, seed: int, reality: RealityEffects | None = None) -> tuple[pd.DataFrame, list[dict]]:
    """Record ``teleop["episodes_per_task"]`` demonstrations of every task in the twin world
    ``params``, with its ``reality`` effects around it (a lab camera's lens and exposure, late
    and loose servos; None: none), into the LeRobot dataset at ``dataset``; returns the true
    initial poses (one row per episode and object) and the attempt log (per attempt: task,
    attempt, success, length, wall_s, and for a failed one the operator's ``phase``, ``reason``
    and ``detail``).

    ``teleop``, ``world``, ``suite``: those config groups; ``seed``: the experiment's seed.
    """
    operator_cfg = OperatorConfig(**(teleop.get("operator") or {}))
    robot = world_robot(world)
    names = robot.feature_names
    features = lerobot_features(names, names, world["cameras"], image_size(world))
    truth, attempts = [], []
    with DatasetRecorder(dataset, "local/teleop", round(robot.control_hz), features, robot.type,
                         video=teleop["video"]) as rec:
        for task_index, task in enumerate(tasks):
            env = make_reality_env(task, world, params, reality, suite_cfg=suite)
            rng = np.random.default_rng([seed, task_index, 11])
            kept = tries = 0
            progress = tqdm(total=teleop["episodes_per_task"], desc=f"teleop {task}", mininterval=5)
            while kept < teleop["episodes_per_task"]:
                if tries >= teleop["max_attempts_factor"] * teleop["episodes_per_task"]:
                    raise R2SError(f"task {task}: only {kept} successful demonstrations in {tries} attempts")
                started = time.perf_counter()
                poses = env.sample_initial_poses(rng)
                obs = env.reset(poses, seed=int(rng.integers(2**31)))
                initial = env.object_poses()
                operator = make_operator(task, env, rng, operator_cfg)
                steps = run_episode(env, operator, robot.steps_in(teleop["max_duration_s"]), obs)
                failure = operator.failure()
                tries += 1
                attempts.append({"task": task, "attempt": tries, "success": failure is None, "length": len(steps),
                                 "wall_s": time.perf_counter() - started,
                                 **(failure.row() if failure is not None else {})})
                if failure is not None:
                    log.info("task %s attempt %d failed in %s", task, tries, failure)
                    if not teleop["keep_failed"]:
                        continue
                # Encoded while the operator records the next take (when the job has two threads).
                index = rec.submit_episode(steps, env.task.instruction)
                kept += 1
                progress.update()
                truth += truth_rows(index, task, env, initial)
            progress.close()
            env.close()
            mine = [a for a in attempts if a["task"] == task]
            rate = np.mean([a["success"] for a in mine])
            why = summary(a for a in mine if not a["success"])
            log.info("task %s: scripted teleop success %.1f%% over %d attempts%s", task, 100 * rate, tries,
                     f"; failed: {why}" if why else "")
    return pd.DataFrame(truth), attempts
