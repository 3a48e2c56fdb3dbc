"""Closed-loop rollouts of one candidate on one arm (sim, or the real side), as one folder.

The candidate is a policy trained here, a checkpoint folder, or a policy server; all are driven
through the same receding horizon. :func:`run_candidate` writes, into one folder:
episodes.parquet (one row per episode), videos/<id>.mp4 and trajectories/<id>.parquet. Episode
ids are opaque hashes so no file name tells a judge which policy it is watching.

Each finished episode is kept in a sibling folder (`.<folder>.episodes/`) until the whole set
is done, so a job that dies (a server gone, a killed machine) resumes with the episodes it had
not finished yet; that folder is discarded when the config, inits, world or policy change.
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
from r2s_eval.rollout.inits import poses_of
from r2s_eval.rollout.loop import episode_id, run_episode
from r2s_eval.rollout.video import write_video
from r2s_eval.sim import ACTION_DIM, get_task, load_world_params
from r2s_eval.sim.build import make_env
from r2s_eval.utils.io import atomic_dir, config_hash, file_sha256, write_json, write_parquet

log = logging.getLogger("r2s_eval.rollout")


def select_inits(inits: pd.DataFrame, arm: str, real_inits_per_task: int | None) -> pd.DataFrame:
    """The real side runs the same seeded configurations, fewer of them when
    ``real_inits_per_task`` says so: a prefix of every task's inits."""
    if arm == "real" and real_inits_per_task is not None:
        inits = inits[inits["init_id"] < int(real_inits_per_task)]
    return inits


def planned_episodes(inits: pd.DataFrame, arm: str, policy: str, seed: int) -> list[tuple[str, int, int, str]]:
    """(task, init_id, episode seed, episode id) of every episode, in the inits' order."""
    planned = []
    for task, init_id in inits[["task", "init_id"]].drop_duplicates().itertuples(index=False):
        episode_seed = int(np.random.default_rng([seed, int(init_id)]).integers(2**31))
        planned.append((task, init_id, episode_seed, episode_id(arm, policy, task, init_id, episode_seed)))
    return planned


def episodes_identity(cfg: dict, policy_cfg: dict, policy, inits: str, twin: str | None, trained_dir: str | None) -> str:
    """What the finished episodes depend on: config (``cfg``: everything the job was configured
    with), inits, world, and the policy's content."""
    parts = {"cfg": cfg, "inits": file_sha256(inits), "twin": file_sha256(twin) if twin else None}
    if not is_external(policy_cfg):
        parts["policy"] = checkpoint_hash(trained_dir)
    elif policy_cfg["type"] == "server":
        parts["policy"] = policy.metadata()  # what the server says it serves, not where it runs
    # (a checkpoint's content hash is part of its config slice already)
    return config_hash(parts)


def episode_store(out: Path, identity: str) -> Path:
    """The sibling folder that keeps finished episodes across interrupted runs."""
    store = out.with_name(f".{out.name}.episodes")
    key_file = store / "identity.json"
    if store.exists() and (not key_file.is_file() or json.loads(key_file.read_text()) != identity):
        shutil.rmtree(store)  # made by another config or policy: nothing in it is ours
    store.mkdir(parents=True, exist_ok=True)
    key_file.write_text(json.dumps(identity))
    return store


def _collect(out: Path, store: Path, planned: list) -> pd.DataFrame:
    """Move the finished episodes into ``out`` (atomically) and drop the store."""
    rows = []
    with atomic_dir(out) as tmp:
        (tmp / "videos").mkdir()
        (tmp / "trajectories").mkdir()
        for _, _, _, ep in planned:
            row = json.loads((store / ep / "row.json").read_text())
            stats = row.pop("policy_stats")
            shutil.copyfile(store / ep / f"{ep}.mp4", tmp / row["video_path"])
            shutil.copyfile(store / ep / f"{ep}.parquet", tmp / row["trajectory_path"])
            rows.append((row, stats))
        episodes = pd.DataFrame([r for r, _ in rows])
        totals = {k: sum(s[k] for _, s in rows) for k in ("steps", "model_calls", "inference_s")}
        write_parquet(tmp / "episodes.parquet", episodes, metadata={"stage": "rollout", "policy_stats": totals})
    shutil.rmtree(store)
    return episodes


def run_candidate(out: Path, *, policy: str, arm: str, seed: int, rollout: dict, world: dict, policy_cfg: dict,
                  inits: str, twin: str | None = None, trained_dir: str | None = None,
                  transport: dict | None = None) -> pd.DataFrame:
    """Roll out candidate ``policy`` from every init of ``inits`` (a parquet of rollout_inits)
    on ``arm``, in the world ``twin`` (world parameters; ``None``: nominal), into ``out``;
    returns the episode table.

    ``rollout``, ``world``: those config groups; ``seed``: the experiment's seed;
    ``policy_cfg``: what decides the candidate's rollouts; ``trained_dir``: its folder when
    trained here; ``transport``: where a checkpoint or server lies (kept out of the episodes'
    identity: moving it changes no result).
    """
    cfg = {"arm": arm, "policy": policy, "policy_cfg": policy_cfg, "rollout": rollout, "seed": seed, "world": world}
    params = load_world_params(twin) if twin else None
    table = select_inits(pd.read_parquet(inits), arm, rollout.get("real_inits_per_task"))
    source = {**policy_cfg, **(transport or {})}
    model = open_policy(source, policy, trained_dir=trained_dir, device=rollout.get("device", "cpu"))
    runner = RecedingHorizon(model, rollout["chunk_size"], rollout["n_action_steps"],
                             action_map(policy_cfg, ACTION_DIM), seed=seed)
    store = episode_store(out, episodes_identity(cfg, policy_cfg, model, inits, twin, trained_dir))
    # Render only what the policy looks at: the other cameras cost time and change nothing.
    cameras = [k.removeprefix("observation.images.") for k in runner.image_keys]
    envs = {}
    planned = planned_episodes(table, arm, policy, seed)
    try:
        for task, init_id, episode_seed, ep in tqdm(planned, desc=f"rollout {arm}/{policy}", mininterval=5):
            if (store / ep / "row.json").is_file():
                continue  # finished before the job was interrupted
            if task not in envs:
                envs[task] = make_env(task, world, params, cameras=cameras)
            runner.reset(seed=episode_seed)
            try:
                result = run_episode(envs[task], runner, poses_of(table, task, init_id), episode_seed,
                                     rollout["max_steps"], rollout["video_camera"],
                                     video_size=rollout.get("video_size"))
            except PolicyError as exc:
                raise PolicyError(f"{exc} [{arm} rollout, task {task}, init {init_id}]") from exc
            with atomic_dir(store / ep) as tmp:
                write_video(tmp / f"{ep}.mp4", result.frames, rollout["video_fps"])
                write_parquet(tmp / f"{ep}.parquet", result.trajectory)
                write_json(tmp / "row.json", {
                    "episode_id": ep, "policy": policy, "arm": arm, "task": task,
                    "instruction": get_task(task).instruction, "init_id": int(init_id), "seed": episode_seed,
                    "success": bool(result.success), "length": int(result.length),
                    "video_path": f"videos/{ep}.mp4", "trajectory_path": f"trajectories/{ep}.parquet",
                    "policy_stats": runner.stats,
                })
            log.info("%s init %d: %s in %d steps", task, init_id, "success" if result.success else "failure", result.length)
    finally:
        model.close()
    episodes = _collect(out, store, planned)
    log.info("success rate %.2f over %d episodes", episodes["success"].mean(), len(episodes))
    return episodes
