"""Closed-loop rollouts of one candidate on one arm (sim, or the real side), as one folder.

The candidate is a policy trained here, a checkpoint folder, or a policy server; all are driven
through the same receding horizon, `batch_episodes` episodes side by side
(`r2s_eval.rollout.batch`: one batched model call per query step; an episode's bytes do not
depend on how many run beside it). :func:`run_candidate` writes, into one folder:
episodes.parquet (one row per episode), videos/<id>.mp4 and trajectories/<id>.parquet. Episode
ids are opaque hashes so no file name tells a judge which policy it is watching.

Each finished episode is kept in a sibling folder (`.<folder>.episodes/`, `r2s_eval.rollout.episode_store`)
as soon as it ends, until
the whole set is done, so a job that dies (a server gone, a killed machine) resumes with the
episodes it had not finished yet; that folder is discarded when the config, inits, world or
policy change (not when `batch_episodes` or the thread count do: they change no result).
"""

from __future__ import annotations

import logging
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from r2s_eval.horizon import Horizon
from r2s_eval.policy_sources import (
    action_map,
    checkpoint_hash,
    is_external,
    open_policy,
    unwrap_variant,
)
from r2s_eval.rollout.batch import EnvPool, PlannedEpisode, run_batched
from r2s_eval.rollout.episode_store import (
    EpisodeFolder,
    collect_episodes,
    episode_store,
)
from r2s_eval.policies.execution import Execution
from r2s_eval.rollout.inits import episode_seed, poses_of
from r2s_eval.rollout.loop import EpisodeRecorder, episode_id, video_frame_every
from r2s_eval.sim import get_task, load_world_params, world_robot
from r2s_eval.twin.reality import load_reality_effects, make_world_env
from r2s_eval.utils.io import config_hash, file_sha256

log = logging.getLogger("r2s_eval.rollout")
# Rollout settings that change no result (the workflow keeps them out of the rerun check too).
UNTRACKED = ("batch_episodes",)


def select_inits(inits: pd.DataFrame, arm: str, real_inits_per_task: int | None) -> pd.DataFrame:
    """The real side runs the same seeded configurations, fewer of them when
    ``real_inits_per_task`` says so: a prefix of every task's inits."""
    if arm == "real" and real_inits_per_task is not None:
        inits = inits[inits["init_id"] < int(real_inits_per_task)]
    return inits


def planned_episodes(inits: pd.DataFrame, arm: str, policy: str, seed: int) -> list[PlannedEpisode]:
    """Every episode, in the inits' order; its index there is the policy slot it runs in."""
    planned = []
    for task, init_id in inits[["task", "init_id"]].drop_duplicates().itertuples(index=False):
        seed_of_episode = episode_seed(seed, init_id)
        planned.append(PlannedEpisode(len(planned), task, int(init_id), seed_of_episode,
                                      episode_id(arm, policy, task, init_id, seed_of_episode), poses_of(inits, task, init_id)))
    return planned


def episodes_identity(cfg: dict, policy_cfg: dict, policy, inits: str, world_params: str | None,
                      trained_dir: str | None) -> str:
    """What the finished episodes depend on: config (``cfg``: everything the job was configured
    with), inits, world, and the policy's content."""
    parts = {"cfg": cfg, "inits": file_sha256(inits), "twin": file_sha256(world_params) if world_params else None}
    policy_cfg, _ = unwrap_variant(policy_cfg)  # a variant's weights are its base's
    if not is_external(policy_cfg):
        parts["policy"] = checkpoint_hash(trained_dir)
    elif policy_cfg["type"] == "server":
        parts["policy"] = policy.metadata()  # what the server says it serves, not where it runs
    # (a checkpoint's content hash is part of its config slice already)
    return config_hash(parts)


def video_size(rollout: dict, arm: str) -> tuple[int, int] | None:
    """The size of an arm's rollout videos: the judges' ``video_size`` for sim rollouts,
    ``real_video_size`` for the real side, which no judge sees (None: the policy's own image)."""
    return rollout.get("real_video_size") if arm == "real" else rollout.get("video_size")


def run_candidate(out: Path, *, policy: str, arm: str, seed: int, rollout: dict, world: dict, policy_cfg: dict,
                  inits: str, world_params: str | None = None, trained_on: str | None = None,
                  trained_dir: str | None = None, tasks: list[str] | None = None,
                  transport: dict | None = None, batch_episodes: int = 1, threads: int = 1) -> pd.DataFrame:
    """Roll out candidate ``policy`` from every init of ``inits`` (a parquet of rollout_inits)
    on ``arm``, in the world ``world_params`` (a world-parameter JSON: the calibrated sim's, or the
    twin's or a twin ablation's, whose reality effects then act around the simulation:
    ``r2s_eval.twin.reality.make_world_env``; ``None``: nominal), into ``out``; returns the
    episode table. ``trained_on``: the arm
    whose data trained the checkpoint, where it is not ``arm`` (a cross-evaluation: its rows say so).
    ``tasks``: only these tasks' inits (the judges' resolution sweep, ``resolution.tasks``); None: all.

    ``rollout``, ``world``: those config groups; ``seed``: the experiment's seed;
    ``policy_cfg``: what decides the candidate's rollouts (a variant's: its base's under `weights`
    and its execution change, ``r2s_eval.policies.execution``); ``trained_dir``: its folder when
    trained here (a variant's: its base's); ``transport``: where a checkpoint or server lies (kept out of the episodes'
    identity: moving it changes no result); ``batch_episodes``: episodes stepped side by side;
    ``threads``: worker threads for physics, rendering and video (model calls stay on one:
    neither changes a result, so neither is part of the identity either).
    """
    rollout = {k: v for k, v in rollout.items() if k not in UNTRACKED}
    cfg = {"arm": arm, "policy": policy, "policy_cfg": policy_cfg, "rollout": rollout, "seed": seed, "world": world}
    if trained_on is not None:
        cfg["trained_on"] = trained_on
    if tasks is not None:
        cfg["tasks"] = list(tasks)
    params = load_world_params(world_params) if world_params else None
    reality = load_reality_effects(world_params) if world_params else None
    table = select_inits(pd.read_parquet(inits), arm, rollout.get("real_inits_per_task"))
    if tasks is not None:
        table = table[table["task"].isin(tasks)]
    weights_cfg, execution_cfg = unwrap_variant(policy_cfg)
    robot = world_robot(world)
    execution = None
    if execution_cfg is not None:
        grippers = [i for i, f in enumerate(robot.features) if f.joint is None]
        # Each gripper's open and closed commands (closing 0 and 1) in the action's units: a fumble opens it.
        home = robot.home_targets()
        gripper_open, gripper_closed = (robot.from_model({arm: (q, closing) for arm, (q, _) in home.items()})[grippers]
                                        for closing in (0.0, 1.0))
        execution = Execution.from_config(
            execution_cfg, joints=[i for i, f in enumerate(robot.features) if f.joint is not None], grippers=grippers,
            gripper_open=gripper_open, gripper_closed=gripper_closed)
    source = {**weights_cfg, **(transport or {})}
    model = open_policy(source, policy, trained_dir=trained_dir, device=rollout.get("device", "cpu"),
                        call_batch=rollout["model_batch"])
    try:
        horizon = Horizon.from_config(rollout["horizon"])
        horizon.check(model.spec.max_chunk, f"policy {policy!r}")  # before any episode starts
        store = episode_store(out, episodes_identity(cfg, policy_cfg, model, inits, world_params, trained_dir))
        # Render only what the policy looks at: the other cameras cost time and change nothing.
        cameras = [k.removeprefix("observation.images.") for k in model.spec.cameras]
        planned = planned_episodes(table, arm, policy, seed)
        todo = [p for p in planned if not (store / p.episode_id / "row.json").is_file()]  # the rest finished before
        progress = tqdm(total=len(planned), initial=len(planned) - len(todo), desc=f"rollout {arm}/{policy}", mininterval=5)

        def finished(p: PlannedEpisode, episode: EpisodeRecorder, stats: dict, folder: EpisodeFolder) -> None:
            ep = p.episode_id
            cross = {} if trained_on is None else {"trained_on": trained_on}
            folder.finish({
                "episode_id": ep, "policy": policy, "arm": arm, **cross, "task": p.task,
                "instruction": get_task(p.task, world).instruction, "init_id": p.init_id, "seed": p.seed,
                "success": bool(episode.success), "length": len(episode.rows),
                "video_path": f"videos/{ep}.mp4", "trajectory_path": f"trajectories/{ep}.parquet",
                "policy_stats": stats,
            }, episode.result().trajectory)
            progress.update()

        run_batched(
            model, todo, EnvPool(lambda task, **shared: make_world_env(task, world, params, reality, cameras=cameras,
                                                                       **shared)),
            arm=arm, horizon=horizon,
            action_map=action_map(weights_cfg, robot.action_dim), max_steps=robot.steps_in(rollout["max_duration_s"]),
            video_camera=rollout["video_camera"], video_size=video_size(rollout, arm),
            open_episode=lambda p: EpisodeFolder(store, p, rollout["video_fps"]), on_finished=finished,
            batch_episodes=batch_episodes, threads=threads,
            frame_every=video_frame_every(rollout["video_fps"], robot.control_dt_s), execution=execution,
        )
        progress.close()
    finally:
        model.close()
    episodes = collect_episodes(out, store, planned)
    log.info("success rate %.2f over %d episodes", episodes["success"].mean(), len(episodes))
    return episodes
