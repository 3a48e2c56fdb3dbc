"""Stage: closed-loop rollouts of one trained policy on one arm (sim, or the real side).

Writes, into one folder: episodes.parquet (one row per episode), videos/<id>.mp4 and
trajectories/<id>.parquet. Episode ids are opaque hashes so no file name tells a judge
which policy it is watching.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.policies import load_policy
from r2s_eval.rollout import episode_id, run_episode, write_video
from r2s_eval.rollout.inits import poses_of
from r2s_eval.sim import get_task
from r2s_eval.stages import _cli
from r2s_eval.stages._world import load_world_params, make_env
from r2s_eval.utils.io import atomic_dir, write_parquet
from r2s_eval.utils.numerics import deterministic_torch

log = logging.getLogger("r2s_eval.rollout")


def main(args) -> None:
    deterministic_torch(1)  # the rule gives this job one core
    cfg = args.cfg
    rollout, world = cfg["rollout"], cfg["world"]
    params = load_world_params(args.twin) if args.twin else None
    inits = pd.read_parquet(args.inits)
    if cfg["arm"] == "real" and rollout.get("real_inits_per_task") is not None:
        # The same seeded configurations, fewer of them: a prefix of every task's inits.
        inits = inits[inits["init_id"] < int(rollout["real_inits_per_task"])]
    runner = load_policy(args.policy, chunk_size=rollout["chunk_size"], n_action_steps=rollout["n_action_steps"], seed=cfg["seed"])
    # Render only what the policy looks at: the other cameras cost time and change nothing.
    cameras = [k.removeprefix("observation.images.") for k in runner.image_keys]
    rows, envs = [], {}
    with atomic_dir(args.out) as out:
        (out / "videos").mkdir()
        (out / "trajectories").mkdir()
        keys = inits[["task", "init_id"]].drop_duplicates().itertuples(index=False)
        for task, init_id in tqdm(list(keys), desc=f"rollout {cfg['arm']}/{cfg['policy']}", mininterval=5):
            if task not in envs:
                envs[task] = make_env(task, world, params, cameras=cameras)
            env = envs[task]
            seed = int(np.random.default_rng([cfg["seed"], int(init_id)]).integers(2**31))
            runner.reset(seed=seed)
            result = run_episode(env, runner, poses_of(inits, task, init_id), seed, rollout["max_steps"], rollout["video_camera"])
            ep = episode_id(cfg["arm"], cfg["policy"], task, init_id, seed)
            write_video(out / "videos" / f"{ep}.mp4", result.frames, rollout["video_fps"])
            write_parquet(out / "trajectories" / f"{ep}.parquet", result.trajectory)
            rows.append({
                "episode_id": ep, "policy": cfg["policy"], "arm": cfg["arm"], "task": task,
                "instruction": get_task(task).instruction, "init_id": int(init_id), "seed": seed,
                "success": result.success, "length": result.length,
                "video_path": f"videos/{ep}.mp4", "trajectory_path": f"trajectories/{ep}.parquet",
            })
            log.info("%s init %d: %s in %d steps", task, init_id, "success" if result.success else "failure", result.length)
        episodes = pd.DataFrame(rows)
        write_parquet(out / "episodes.parquet", episodes, metadata={"stage": "rollout", "policy_stats": runner.stats})
    log.info("success rate %.2f over %d episodes", episodes["success"].mean(), len(episodes))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--policy", required=True, help="trained policy folder")
    p.add_argument("--inits", required=True)
    p.add_argument("--twin", help="world parameters of the real side (the reality twin)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
