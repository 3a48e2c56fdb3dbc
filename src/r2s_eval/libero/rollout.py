"""Closed-loop LIBERO rollouts of one candidate, written as our rollout folder.

The candidate (a checkpoint loaded here, or a policy server reached through our client) is served
by our `PolicyServer` on loopback; `workers` LIBERO processes (`libero_side.py`, in LIBERO's own
environment) are its clients, each stepping a share of the episodes, one task's environment at
a time. Each finished episode comes back as an npz and is turned here into what our own
rollouts write (``r2s_eval.rollout.candidate``): an H.264 judge video, a trajectory parquet and a
row of episodes.parquet. Finished episodes are kept in the same sibling store as our rollouts',
so a run that dies (a crashed LIBERO process, a killed job) resumes with the rest.

Every policy runs the same episodes: task by task, the first ``episodes_per_task`` official
initial states in order, each with a seed that depends on the experiment's seed, the task and the
init only.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd

from r2s_eval.horizon import Horizon
from r2s_eval.libero import ACTION_DIM, CAMERAS, CONTROL_HZ, OFFICIAL_INIT_STATES, STATE_DIM, LiberoTask, selected_tasks
from r2s_eval.libero.environment import LIBERO_SIDE_SCRIPT, requirements_hash
from r2s_eval.policies.interface import IMAGE_PREFIX, ChunkPolicy, PolicyError, PolicySpec
from r2s_eval.policy_sources import checkpoint_hash, is_external, open_policy
from r2s_eval.rollout.batch import PlannedEpisode
from r2s_eval.rollout.episode_store import EpisodeFolder, collect_episodes, episode_store
from r2s_eval.rollout.loop import episode_id, video_frame_every
from r2s_eval.utils.io import config_hash

log = logging.getLogger("r2s_eval.libero")
POLL_S = 0.5


def policy_cameras(spec: PolicySpec, cameras: dict[str, str], policy: str, key_map=None) -> dict[str, str]:
    """The observation keys the policy reads, each with the LIBERO camera that feeds it
    (`cameras`: libero.observation.cameras, keys without the observation.images. prefix); a
    policy LIBERO cannot feed is an error before any episode starts. `key_map`: a server's
    (r2s_eval.serving.keymap.KeyMap), whose keys' cameras and state slices are checked by key."""
    if key_map is not None:
        key_map.check_streams(cameras, STATE_DIM, f"policy {policy!r}", "LIBERO (libero.observation.cameras)")
    offered = {IMAGE_PREFIX + k: c for k, c in cameras.items()}
    problems = []
    unmapped = [k for k in spec.cameras if k not in offered]
    if unmapped:
        problems.append(f"it reads cameras {unmapped}, libero.observation.cameras offers {sorted(offered)}")
    if spec.action_dim != ACTION_DIM:
        problems.append(f"it returns {spec.action_dim}-D actions, LIBERO takes {ACTION_DIM}-D (end-effector delta + gripper)")
    if spec.uses_state and spec.state_dim not in (None, STATE_DIM):
        problems.append(f"it expects a {spec.state_dim}-D state, LIBERO gives {STATE_DIM}-D")
    if problems:
        raise PolicyError(f"policy {policy!r} does not fit LIBERO: " + "; ".join(problems))
    bad = {k: c for k, c in cameras.items() if c not in CAMERAS}
    if bad:
        raise PolicyError(f"libero.observation.cameras: {bad} name no LIBERO camera; valid: {list(CAMERAS)}")
    return {k: offered[k] for k in spec.cameras}


def planned_episodes(tasks: list[LiberoTask], episodes_per_task: int, seed: int, policy: str) -> list[PlannedEpisode]:
    if not 1 <= episodes_per_task <= OFFICIAL_INIT_STATES:
        raise PolicyError(f"libero.episodes_per_task must be 1..{OFFICIAL_INIT_STATES} (the official initial states)")
    planned = []
    for task in tasks:
        for k in range(episodes_per_task):
            episode_seed = int(np.random.default_rng([seed, task.index, k, sum(map(ord, task.suite))]).integers(2**31))
            planned.append(PlannedEpisode(len(planned), task.name, k, episode_seed,
                                          episode_id("libero", policy, task.name, k, episode_seed), {}))
    return planned


def shards(todo: list[PlannedEpisode], workers: int) -> list[list[PlannedEpisode]]:
    """Whole tasks per worker (a LIBERO environment takes seconds to make), balanced by count."""
    by_task: dict[str, list[PlannedEpisode]] = {}
    for p in todo:
        by_task.setdefault(p.task, []).append(p)
    out: list[list[PlannedEpisode]] = [[] for _ in range(max(1, min(workers, len(by_task))))]
    for episodes in sorted(by_task.values(), key=len, reverse=True):
        min(out, key=len).extend(episodes)
    return [s for s in out if s]


def world_job(libero: dict, horizon: Horizon, cameras: dict[str, str], episodes: list[PlannedEpisode],
              tasks: dict[str, LiberoTask], port: int, out: Path) -> dict:
    video = libero["video"]
    return {
        "server": {"host": "127.0.0.1", "port": port},
        "cameras": cameras,
        "image_size": list(libero["observation"]["image_size"]),
        "rotate_180": bool(libero["observation"]["rotate_180"]),
        "video": {"camera": video["camera"], "size": list(video["size"]), "every": video_frame_every(video["fps"], 1 / CONTROL_HZ)},
        "settle_steps": int(libero["settle_steps"]),
        "execute": horizon.execute,  # actions of each chunk run before the next query
        "render": libero["render"],
        "out": str(out),
        "episodes": [{"episode_id": p.episode_id, "suite": tasks[p.task].suite, "task_index": tasks[p.task].index,
                      "init_index": p.init_id, "seed": p.seed, "max_steps": tasks[p.task].max_steps} for p in episodes],
    }


def trajectory_of(record) -> pd.DataFrame:
    """Our trajectory columns from a LIBERO record (one arm: both end-effector columns hold it;
    progress is LIBERO's success predicate, the only progress LIBERO defines)."""
    n = len(record["action"])
    eef = record["eef_pos"].astype(float).tolist()
    return pd.DataFrame({
        "step": np.arange(n),
        "time_s": np.arange(n) / CONTROL_HZ,
        "state": record["state"].astype(float).tolist(),
        "action": record["action"].astype(float).tolist(),
        "ee_pos_left": eef,
        "ee_pos_right": eef,
        "contact_force_n": record["contact_force_n"].astype(float),
        "progress": record["success"].astype(float),
        "success": record["success"].astype(bool),
    })


def keep_episode(npz: Path, planned: PlannedEpisode, store: Path, policy: str, fps: int) -> None:
    """One finished LIBERO episode into the store, as our rollouts keep theirs; the npz goes."""
    with np.load(npz) as record:
        folder = EpisodeFolder(store, planned, fps)
        try:
            for frame in record["frames"]:
                folder.add(frame)
            ep = planned.episode_id
            folder.finish({
                "episode_id": ep, "policy": policy, "arm": "sim", "task": planned.task,
                "instruction": str(record["instruction"]), "init_id": planned.init_id, "seed": planned.seed,
                "success": bool(record["final_success"]), "length": int(len(record["action"])),
                "video_path": f"videos/{ep}.mp4", "trajectory_path": f"trajectories/{ep}.parquet",
                "init_state_sha256": str(record["init_state_sha256"]),
                "policy_stats": {"steps": int(len(record["action"])), "model_calls": int(record["model_calls"]),
                                 "inference_s": float(record["inference_s"])},
            }, trajectory_of(record))
        except BaseException:
            folder.abort()
            raise
    npz.unlink()


def failure_text(out: Path, returncode: int, policy: str) -> str:
    """What a failed LIBERO process was doing: its own report, else its last episode's marker."""
    failure = json.loads((out / "failed.json").read_text()) if (out / "failed.json").is_file() else None
    running = failure if failure and "suite" in failure else (
        json.loads((out / "current.json").read_text()) if (out / "current.json").is_file() else None)
    where = (f"{running['suite']} task {running['task_index']} init {running['init_index']}"
             if running else "before its first episode")
    why = failure["error"] if failure else f"the process ended with status {returncode}"
    return f"LIBERO process failed on {where} (policy {policy!r}): {why}"


def run_world_processes(python: Path, jobs: list[dict], work: Path, on_episode, log_file: Path | None = None,
                        policy: str = "?") -> list[str]:
    """Run one LIBERO process per job, handing every finished episode (npz path) to
    `on_episode` as it comes; returns the failures' texts (empty when all finished)."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONNOUSERSITE": "1"}
    env.pop("PYTHONPATH", None)  # our packages must not leak into LIBERO's environment
    procs = []
    for i, job in enumerate(jobs):
        job_file = work / f"job{i}.json"
        job_file.write_text(json.dumps(job))
        out = open(log_file or os.devnull, "a")
        procs.append((subprocess.Popen([str(python), str(LIBERO_SIDE_SCRIPT), str(job_file)], stdout=out,
                                       stderr=subprocess.STDOUT, env=env), job, out))
    try:
        while True:
            running = [p for p, _, _ in procs if p.poll() is None]
            for _, job, _ in procs:
                for npz in sorted(Path(job["out"]).glob("*.npz")):
                    if not npz.name.startswith("."):
                        on_episode(npz)
            if not running:
                break
            time.sleep(POLL_S)
    finally:
        for p, _, out in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
            out.close()
    return [failure_text(Path(job["out"]), p.returncode, policy) for p, job, _ in procs if p.returncode != 0]


def run_libero_candidate(out: Path, *, policy: str, seed: int, libero: dict, rollout: dict, policy_cfg: dict,
                         python: Path, transport: dict | None = None, workers: int = 1,
                         world_log: Path | None = None) -> pd.DataFrame:
    """Roll out candidate `policy` (a checkpoint or server entry) on the configured LIBERO tasks
    into `out`; returns the episode table. `python`: LIBERO's environment's interpreter;
    `workers`: LIBERO processes side by side (it changes no result); `world_log`: where their
    output goes."""
    from r2s_eval.serving.policy_server import PolicyServer

    if not is_external(policy_cfg):
        raise PolicyError(f"policy {policy!r}: LIBERO candidates are `type: checkpoint` or `type: server` entries")
    tasks = selected_tasks(libero["tasks"], libero["max_steps"])
    by_name = {t.name: t for t in tasks}
    planned = planned_episodes(tasks, int(libero["episodes_per_task"]), seed, policy)
    source = {**policy_cfg, **(transport or {})}
    model: ChunkPolicy = open_policy(source, policy, device=rollout.get("device", "cpu"), call_batch=1)
    server = None
    try:
        cameras = policy_cameras(model.spec, dict(libero["observation"]["cameras"]), policy,
                                 getattr(model, "key_map", None))
        horizon = Horizon.from_config(rollout["horizon"])
        horizon.check(model.spec.max_chunk, f"policy {policy!r}")
        identity = {"libero": libero, "rollout": {"horizon": horizon.to_dict()},
                    "seed": seed, "policy_cfg": policy_cfg, "requirements": requirements_hash(),
                    "policy": checkpoint_hash(source["path"]) if policy_cfg["type"] == "checkpoint" else model.metadata()}
        store = episode_store(out, config_hash(identity))
        todo = [p for p in planned if not (store / p.episode_id / "row.json").is_file()]
        log.info("%d of %d episodes to run (%d finished before)", len(todo), len(planned), len(planned) - len(todo))
        if todo:
            server = PolicyServer(model, host="127.0.0.1", port=0)
            port = server.start()
            work = store / ".world"
            shutil.rmtree(work, ignore_errors=True)
            work.mkdir()
            jobs = [world_job(libero, horizon, cameras, shard, by_name, port, work / f"out{i}")
                    for i, shard in enumerate(shards(todo, workers))]
            by_id = {p.episode_id: p for p in todo}
            fps = int(libero["video"]["fps"])
            failures = run_world_processes(
                python, jobs, work, lambda npz: keep_episode(npz, by_id[npz.stem], store, policy, fps), world_log, policy)
            if failures:
                done = sum((store / p.episode_id / "row.json").is_file() for p in planned)
                raise PolicyError("; ".join(failures) + f" ({done} of {len(planned)} episodes are kept; a rerun does the rest)")
            shutil.rmtree(work, ignore_errors=True)
    finally:
        if server is not None:
            server.stop()
        model.close()
    episodes = collect_episodes(out, store, planned)
    log.info("LIBERO success rate %.2f over %d episodes", episodes["success"].mean(), len(episodes))
    return episodes
