"""Stage: the scripted operator records the teleop dataset in the reality twin.

Operators keep the demonstrations that succeed (as a lab discards botched takes); every
attempt is logged. The twin's true initial poses go to a separate file used only to score
the initial-pose estimates.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.data import DatasetRecorder, lerobot_features
from r2s_eval.errors import R2SError
from r2s_eval.sim import get_task
from r2s_eval.sim.teleop import OperatorConfig, make_operator, run_episode
from r2s_eval.sim.world import ARM_JOINTS, ARMS, CONTROL_DT_S
from r2s_eval.stages import _cli
from r2s_eval.stages._world import image_size, load_world_params, make_env, yaw_symmetry
from r2s_eval.utils.io import write_parquet

log = logging.getLogger("r2s_eval.teleop")

JOINT_NAMES = [f"{arm}_{j}" for arm in ARMS for j in (*ARM_JOINTS, "gripper")]


def main(args) -> None:
    cfg = args.cfg
    teleop, world = cfg["teleop"], cfg["world"]
    params = load_world_params(args.twin)
    operator_cfg = OperatorConfig(**(teleop.get("operator") or {}))
    features = lerobot_features(JOINT_NAMES, JOINT_NAMES, world["cameras"], image_size(world))
    truth, attempts = [], []
    with DatasetRecorder(args.dataset, "local/teleop", round(1 / CONTROL_DT_S), features, "r2s_dual_arm") as rec:
        for task_index, task in enumerate(cfg["tasks"]):
            env = make_env(task, world, params, suite_cfg=cfg["suite"])
            rng = np.random.default_rng([cfg["seed"], task_index, 11])
            kept = tries = 0
            progress = tqdm(total=teleop["episodes_per_task"], desc=f"teleop {task}", mininterval=5)
            while kept < teleop["episodes_per_task"]:
                if tries >= teleop["max_attempts_factor"] * teleop["episodes_per_task"]:
                    raise R2SError(f"task {task}: only {kept} successful demonstrations in {tries} attempts")
                started = time.perf_counter()
                poses = env.sample_initial_poses(rng)
                obs = env.reset(poses, seed=int(rng.integers(2**31)))
                initial = env.object_poses()
                steps = run_episode(env, make_operator(task, env, rng, operator_cfg), teleop["max_steps"], obs)
                success = bool(env.is_success())
                tries += 1
                attempts.append({"task": task, "attempt": tries, "success": success, "length": len(steps),
                                 "wall_s": time.perf_counter() - started})
                if not success and not teleop["keep_failed"]:
                    continue
                index = rec.add_episode(steps, get_task(task).instruction)
                kept += 1
                progress.update()
                for name, pose in initial.items():
                    x, y, yaw = pose["planar"]  # the convention of reset() and of the estimates
                    truth.append({"episode_index": index, "task": task, "object": name, "x_m": float(x), "y_m": float(y),
                                  "yaw_rad": float(yaw), "yaw_symmetry": yaw_symmetry(env, name)})
            progress.close()
            env.close()
            rate = np.mean([a["success"] for a in attempts if a["task"] == task])
            log.info("task %s: scripted teleop success %.1f%% over %d attempts", task, 100 * rate, tries)
    write_parquet(args.truth, pd.DataFrame(truth), metadata={"stage": "teleop", "attempts": attempts})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--twin", required=True)
    p.add_argument("--dataset", required=True)
    p.add_argument("--truth", required=True)
    _cli.run(main, p)
