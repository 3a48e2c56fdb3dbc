"""Rollouts per CPU-second: the batched rollout loop against the one-at-a-time loop it replaced.

Both run the same candidate, the CPU line-up's ACT architecture (ResNet18, 32x32 inputs, chunk
25, execute 5), randomly initialised here (or a trained folder with ``--checkpoint``), reading
``--cameras`` of the world's cameras (4: every camera the demo records, at 128 px), from the
same seeded initial configurations, with the demo's rollout settings (judge video of
``head_left`` at 448 px, 150 steps; a random policy never succeeds, so every episode runs them
all). Each writes what the rollout stage writes: an mp4, a trajectory parquet and a row per
episode.

- one at a time: the loop as it was, ``run_episode`` with ``RecedingHorizon.act``, one model call
  per query with a single observation (ACT's ResNet run once per camera), the cameras rendered
  and a judge-video frame recorded at every control step (10 fps), every image drawn in the
  model's offscreen buffer (640x480), the video encoded once the episode is over with libx264
  veryfast;
- one at a time, today's model call and renderers: the same loop with the model call the batched
  loop makes (one ResNet pass over every camera's images) and its renderers (a buffer of each
  image's size), so that the gain of running episodes side by side is seen apart from those;
- batched: ``run_candidate`` (the rollout stage's code) with ``--batch`` episodes side by side,
  one model call of ``rollout.model_batch`` rows per query step (one ResNet pass over every
  camera's images, batch norms folded into the convolutions), ``--threads`` worker threads,
  the cameras rendered at query steps only, the judge video at ``rollout.video_fps`` (5 fps),
  encoded as the frames come with libx264 ultrafast (the rollout stage's encoder).

CPU time is the process's (every thread, software GL's included), so running on more cores
counts for nothing: the gain comes from batched model calls and work no longer done. Repeats
interleave the loops so machine load hits them alike; the best repeat of each is reported.

Run: ``python benchmarks/bench_rollout_batch.py [--episodes 32] [--batch 32] [--cameras 4] [--repeats 2]``
"""

from __future__ import annotations

import os

# As the rollout rule runs the stage: llvmpipe rasterises in the thread that renders.
os.environ.setdefault("LP_NUM_THREADS", "0")
# Headless, as r2s_eval sets it: mujoco reads the variable when it is imported, below.
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse
import contextlib
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
import torch

from r2s_eval.config import compose_config
from r2s_eval.horizon import Horizon
from r2s_eval.policies import RecedingHorizon
from r2s_eval.policies.types import act as act_type
from r2s_eval.policies.interface import ActionMap
from r2s_eval.policies.lerobot_policy import load_lerobot_policy
from r2s_eval.rollout import run_episode, sample_inits, write_video
from r2s_eval.rollout.candidate import planned_episodes, run_candidate
from r2s_eval.rollout.episode_store import collect_episodes
from r2s_eval.sim import world_config, world_robot
from r2s_eval.sim.build import configured_task, make_env
from r2s_eval.utils.io import write_json, write_parquet
from r2s_eval.paths import CONF_DIR, REPO_ROOT
from r2s_eval.utils.numerics import deterministic_torch

sys.path.insert(0, str(REPO_ROOT))  # the tests' helper package: tests.helpers
from tests.helpers.policies import save_random_policy  # noqa: E402


ROBOT = world_robot(world_config("tabletop"))  # the bundled world's robot: its action layout, rig and control rate
ACTION_DIM, CAMERA_NAMES = ROBOT.action_dim, ROBOT.camera_names


@contextlib.contextmanager
def per_camera_backbone():
    """ACT's model call as the one-at-a-time loop made it: its ResNet once per camera."""
    one_pass = act_type.one_backbone_pass
    act_type.one_backbone_pass = lambda model, images: contextlib.nullcontext()
    try:
        yield
    finally:
        act_type.one_backbone_pass = one_pass


def one_at_a_time(out: Path, trained: Path, inits, cfg: dict, as_it_was: bool = True) -> None:
    """The rollout loop as it was: one episode after the other, one observation per model call
    (with `as_it_was`, its model call and renderers as they were too)."""
    with per_camera_backbone() if as_it_was else contextlib.nullcontext():
        _one_at_a_time(out, trained, inits, cfg, as_it_was)


def _one_at_a_time(out: Path, trained: Path, inits, cfg: dict, model_buffer: bool) -> None:
    rollout, world = cfg["rollout"], cfg["world"]
    model = load_lerobot_policy(trained)  # no fixed call shape: one row per call
    runner = RecedingHorizon(model, Horizon.from_config(rollout["horizon"]), ActionMap(ACTION_DIM))
    cameras = [k.removeprefix("observation.images.") for k in model.spec.cameras]
    planned = planned_episodes(inits, "sim", "act", cfg["seed"])
    store = out.with_name(f".{out.name}.episodes")
    store.mkdir()
    envs, renderers = {}, {}
    for p in planned:
        if p.task not in envs:
            renderers[p.task] = {}
            envs[p.task] = make_env(p.task, world, None, cameras=cameras, renderers=renderers[p.task])
            if model_buffer:  # renderers made as they were: in the model's own offscreen buffer
                for size in (envs[p.task].image_size, tuple(rollout["video_size"])):
                    renderers[p.task][size] = mujoco.Renderer(envs[p.task].model, *size)
        runner.reset(seed=p.seed)
        result = run_episode(envs[p.task], runner, p.object_poses, p.seed, ROBOT.steps_in(rollout["max_duration_s"]),
                             rollout["video_camera"], video_size=rollout["video_size"])  # a frame every step
        folder = store / p.episode_id
        folder.mkdir()
        # 10 fps, encoded with the preset the loop used then (libx264 veryfast)
        write_video(folder / f"{p.episode_id}.mp4", result.frames, round(ROBOT.control_hz), preset="veryfast")
        write_parquet(folder / f"{p.episode_id}.parquet", result.trajectory)
        write_json(folder / "row.json", {
            "episode_id": p.episode_id, "task": p.task, "init_id": p.init_id, "seed": p.seed,
            "success": bool(result.success), "length": int(result.length),
            "video_path": f"videos/{p.episode_id}.mp4", "trajectory_path": f"trajectories/{p.episode_id}.parquet",
            "policy_stats": runner.stats})
    for env in envs.values():
        env.close()
    for task_renderers in renderers.values():
        for renderer in task_renderers.values():
            renderer.close()
    collect_episodes(out, store, planned)


def batched(out: Path, trained: Path, inits_path: Path, cfg: dict, batch: int, threads: int) -> None:
    run_candidate(out, policy="act", arm="sim", seed=cfg["seed"], rollout=cfg["rollout"], world=cfg["world"],
                  policy_cfg={"type": "act"}, inits=str(inits_path), trained_dir=str(trained),
                  batch_episodes=batch, threads=threads)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="cup_on_plate")
    parser.add_argument("--episodes", type=int, default=None,
                        help="episodes per loop and repeat (default: as many as the batched loop runs side by side)")
    parser.add_argument("--batch", type=int, default=None,
                        help="episodes side by side in the batched loop (default: rollout.batch_episodes)")
    parser.add_argument("--threads", type=int, default=1, help="worker threads of the batched loop")
    parser.add_argument("--model-batch", type=int, default=None, help="rows of a model call (default: the demo's)")
    parser.add_argument("--cameras", type=int, default=4, choices=range(1, len(CAMERA_NAMES) + 1),
                        help="cameras the policy reads (the first N of the world's)")
    parser.add_argument("--max-steps", type=int, default=None, help="default: the demo's rollout.max_duration_s at 10 Hz")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--checkpoint", type=Path, help="a trained ACT folder instead of a random one")
    args = parser.parse_args()
    deterministic_torch(1)  # as the rollout stage

    cfg = compose_config(CONF_DIR, experiment="demo")
    cfg["world"]["cameras"] = list(CAMERA_NAMES)
    if args.max_steps:
        cfg["rollout"]["max_duration_s"] = args.max_steps / ROBOT.control_hz
    if args.model_batch:
        cfg["rollout"]["model_batch"] = args.model_batch
    args.batch = args.batch or cfg["rollout"]["batch_episodes"]
    args.episodes = args.episodes or args.batch
    image_hw = (int(cfg["world"]["image_height"]), int(cfg["world"]["image_width"]))
    work = Path(tempfile.mkdtemp(prefix="bench_rollout_batch."))
    try:
        trained = args.checkpoint or save_random_policy(work / "act", list(CAMERA_NAMES[: args.cameras]), image_hw)
        inits = sample_inits([configured_task(args.task, cfg["world"], cfg["suite"])], args.episodes, cfg["seed"])
        inits_path = work / "inits.parquet"
        inits.to_parquet(inits_path)
        loops = {"one at a time": lambda out: one_at_a_time(out, trained, inits, cfg),
                 "one at a time, today's model call and renderers": lambda out: one_at_a_time(out, trained, inits, cfg, False),
                 "batched": lambda out: batched(out, trained, inits_path, cfg, args.batch, args.threads)}
        best = {(name, clock): np.inf for name in loops for clock in ("cpu", "wall")}
        steps = {}
        for repeat in range(args.repeats):
            for i, (name, run) in enumerate(loops.items()):
                out = work / f"out{repeat}_{i}"
                wall, cpu = time.perf_counter(), time.process_time()
                run(out)
                cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
                best[name, "cpu"], best[name, "wall"] = min(best[name, "cpu"], cpu), min(best[name, "wall"], wall)
                steps[name] = int(pd.read_parquet(out / "episodes.parquet")["length"].sum())
        model = load_lerobot_policy(trained)
        print(f"ACT (ResNet18, {model.spec.cameras} at {image_hw[0]} px -> 32 px), task {args.task}, "
              f"{args.episodes} episodes ({steps['batched']} control steps; one at a time: {steps['one at a time']}), "
              f"judge video {cfg['rollout']['video_size'][0]} px, batch {args.batch} episodes, "
              f"model call {cfg['rollout']['model_batch']} rows, {args.threads} worker thread(s), best of {args.repeats}")
        rates = {}
        for name in loops:
            rates[name] = args.episodes / best[name, "cpu"]
            print(f"  {name:48s} {rates[name]:7.4f} rollouts per CPU-second  ({best[name, 'cpu']:6.1f} CPU-s, "
                  f"{best[name, 'wall']:6.1f} s wall, {1e3 * best[name, 'cpu'] / steps[name]:5.1f} CPU-ms per step)")
        for baseline in list(loops)[:2]:
            print(f"  batched / {baseline}: {rates['batched'] / rates[baseline]:.2f}x rollouts per CPU-second")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
