"""Stage: closed-loop rollouts of one candidate on one arm (sim, or the real side).

The candidate is a policy trained here, a checkpoint folder, or a policy server; all are driven
through the same receding horizon. Writes, into one folder: episodes.parquet (one row per
episode), videos/<id>.mp4 and trajectories/<id>.parquet. Episode ids are opaque hashes so no file
name tells a judge which policy it is watching.

Each finished episode is kept in a sibling folder (`.<policy>.episodes/`) until the stage
completes, so a stage that dies (a server gone, a killed machine) resumes with the episodes it
had not finished yet.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.policies import PolicyError, RecedingHorizon
from r2s_eval.policies.sources import action_map, checkpoint_hash, is_external, open_policy
from r2s_eval.rollout import episode_id, run_episode, write_video
from r2s_eval.rollout.inits import poses_of
from r2s_eval.sim import get_task
from r2s_eval.sim.env import ACTION_DIM
from r2s_eval.stages import _cli
from r2s_eval.stages._world import load_world_params, make_env
from r2s_eval.utils.io import atomic_dir, config_hash, file_sha256, write_json, write_parquet
from r2s_eval.utils.numerics import deterministic_torch

log = logging.getLogger("r2s_eval.rollout")


def _identity(args, policy) -> str:
    """What the finished episodes depend on: config, inits, world, and the policy's content."""
    parts = {"cfg": args.cfg, "inits": file_sha256(args.inits), "twin": file_sha256(args.twin) if args.twin else None}
    source = args.cfg["policy_cfg"]
    if not is_external(source):
        parts["policy"] = checkpoint_hash(args.policy)
    elif source["type"] == "server":
        parts["policy"] = policy.metadata()  # what the server says it serves, not where it runs
    # (a checkpoint's content hash is part of its config slice already)
    return config_hash(parts)


def _episode_store(out: Path, identity: str) -> Path:
    store = out.with_name(f".{out.name}.episodes")
    key_file = store / "identity.json"
    if store.exists() and (not key_file.is_file() or json.loads(key_file.read_text()) != identity):
        shutil.rmtree(store)  # made by another config or policy: nothing in it is ours
    store.mkdir(parents=True, exist_ok=True)
    key_file.write_text(json.dumps(identity))
    return store


def main(args) -> None:
    deterministic_torch(1)  # the rule gives this job one core
    cfg = args.cfg
    rollout, world, name = cfg["rollout"], cfg["world"], cfg["policy"]
    params = load_world_params(args.twin) if args.twin else None
    inits = pd.read_parquet(args.inits)
    if cfg["arm"] == "real" and rollout.get("real_inits_per_task") is not None:
        # The same seeded configurations, fewer of them: a prefix of every task's inits.
        inits = inits[inits["init_id"] < int(rollout["real_inits_per_task"])]
    # Where a server or checkpoint lies reaches the stage apart from its config slice: moving it
    # changes no result, so it must not make Snakemake rerun the stage.
    source = {**cfg["policy_cfg"], **json.loads(args.transport or "{}")}
    policy = open_policy(source, name, trained_dir=args.policy, device=rollout.get("device", "cpu"))
    runner = RecedingHorizon(policy, rollout["chunk_size"], rollout["n_action_steps"],
                             action_map(cfg["policy_cfg"], ACTION_DIM), seed=cfg["seed"])
    out = Path(args.out)
    store = _episode_store(out, _identity(args, policy))
    # Render only what the policy looks at: the other cameras cost time and change nothing.
    cameras = [k.removeprefix("observation.images.") for k in runner.image_keys]
    envs = {}
    episodes_to_run = []  # (task, init, seed, episode id), in the inits' order
    for task, init_id in inits[["task", "init_id"]].drop_duplicates().itertuples(index=False):
        seed = int(np.random.default_rng([cfg["seed"], int(init_id)]).integers(2**31))
        episodes_to_run.append((task, init_id, seed, episode_id(cfg["arm"], name, task, init_id, seed)))
    try:
        for task, init_id, seed, ep in tqdm(episodes_to_run, desc=f"rollout {cfg['arm']}/{name}", mininterval=5):
            if (store / ep / "row.json").is_file():
                continue  # finished before the stage was interrupted
            if task not in envs:
                envs[task] = make_env(task, world, params, cameras=cameras)
            runner.reset(seed=seed)
            try:
                result = run_episode(envs[task], runner, poses_of(inits, task, init_id), seed,
                                     rollout["max_steps"], rollout["video_camera"],
                                     video_size=rollout.get("video_size"))
            except PolicyError as exc:
                raise PolicyError(f"{exc} [{cfg['arm']} rollout, task {task}, init {init_id}]") from exc
            with atomic_dir(store / ep) as tmp:
                write_video(tmp / f"{ep}.mp4", result.frames, rollout["video_fps"])
                write_parquet(tmp / f"{ep}.parquet", result.trajectory)
                write_json(tmp / "row.json", {
                    "episode_id": ep, "policy": name, "arm": cfg["arm"], "task": task,
                    "instruction": get_task(task).instruction, "init_id": int(init_id), "seed": seed,
                    "success": bool(result.success), "length": int(result.length),
                    "video_path": f"videos/{ep}.mp4", "trajectory_path": f"trajectories/{ep}.parquet",
                    "policy_stats": runner.stats,
                })
            log.info("%s init %d: %s in %d steps", task, init_id, "success" if result.success else "failure", result.length)
    finally:
        policy.close()
    rows = []
    with atomic_dir(out) as tmp:
        (tmp / "videos").mkdir()
        (tmp / "trajectories").mkdir()
        for _, _, _, ep in episodes_to_run:
            row = json.loads((store / ep / "row.json").read_text())
            stats = row.pop("policy_stats")
            shutil.copyfile(store / ep / f"{ep}.mp4", tmp / row["video_path"])
            shutil.copyfile(store / ep / f"{ep}.parquet", tmp / row["trajectory_path"])
            rows.append((row, stats))
        episodes = pd.DataFrame([r for r, _ in rows])
        totals = {k: sum(s[k] for _, s in rows) for k in ("steps", "model_calls", "inference_s")}
        write_parquet(tmp / "episodes.parquet", episodes, metadata={"stage": "rollout", "policy_stats": totals})
    shutil.rmtree(store)
    log.info("success rate %.2f over %d episodes", episodes["success"].mean(), len(episodes))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--policy", help="trained policy folder (candidates trained here)")
    p.add_argument("--inits", required=True)
    p.add_argument("--twin", help="world parameters of the real side (the reality twin)")
    p.add_argument("--transport", help="JSON: where a checkpoint or server is (path, host, port, ...)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
