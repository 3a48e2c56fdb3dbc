"""Rollout-loop throughput: our closed loop vs bare ``mj_step`` + render of the same scene.

Ours: ``r2s_eval.rollout.run_episode`` in ``TabletopEnv`` with all four cameras (two head,
two wrist) rendered every control step, as the teleop recorder and a four-camera policy
see them: action clipping, 50 physics steps per control step, four renders, the task's
success and progress checks, the per-step trajectory record (poses, contact forces) and
the video frame. The policy replays a scripted demonstration (its cost is not ours).

Baseline, in the same run on the same compiled model: a bare loop of
``mujoco.mj_step(model, data, nstep=50)`` plus ``Renderer.update_scene`` + ``render`` for
the same four cameras at the same size, with the same servo targets (arms and grippers) in
``data.ctrl``, so both simulate the same grasp.

Prints simulated control steps per second for both, physics steps per second, and our
overhead (baseline rate / our rate - 1); the target is at most 30 %. Repeats interleave
the two loops so machine load hits both alike; the best repeat of each is reported, per
wall-clock second and per CPU second of this process (steadier on a shared machine).

Run: ``python benchmarks/bench_rollout_loop.py [--task cup_on_plate] [--repeats 5] [--size 128]``
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from r2s_eval.rollout import run_episode  # noqa: E402
from r2s_eval.sim import TabletopEnv, get_task, world_config, world_robot  # noqa: E402
from r2s_eval.twin.operator import make_operator  # noqa: E402
from r2s_eval.twin.operator import run_episode as run_teleop  # noqa: E402


class Replay:
    """Policy stand-in: returns the recorded actions one by one, then holds the last."""

    def __init__(self, actions: np.ndarray):
        self.actions, self.i = actions, 0

    def reset(self) -> None:
        self.i = 0

    def act(self, obs: dict) -> np.ndarray:
        action = self.actions[min(self.i, len(self.actions) - 1)]
        self.i += 1
        return action


def _clocks() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def ours(env: TabletopEnv, poses, actions: np.ndarray) -> tuple[int, float, float]:
    policy = Replay(actions)
    wall, cpu = _clocks()
    # success_hold_steps beyond the length: every step runs, as in a failed episode.
    result = run_episode(env, policy, poses, seed=0, max_steps=len(actions), video_camera="head_left",
                         success_hold_steps=len(actions) + 1)
    return result.length, time.perf_counter() - wall, time.process_time() - cpu


def bare(env: TabletopEnv, poses, actions: np.ndarray) -> tuple[int, float, float]:
    model, data = env.model, env.data
    env.reset(poses, seed=0)  # same start state; reset itself is not timed
    renderer = env.renderer(env.image_size)
    # The bundled robot's layout, written out: per arm six joint targets and a gripper command
    # (0 open .. 1 closed), the gripper servo's target 0.05 m at open.
    arms = [env._arm_act["left"], env._arm_act["right"]]
    grippers = [env._grip_act["left"], env._grip_act["right"]]
    wall, cpu = _clocks()
    for action in actions:
        # Same servo targets as ours, so the physics (grasp contacts included) is the same.
        data.ctrl[arms[0]] = action[0:6]
        data.ctrl[arms[1]] = action[7:13]
        data.ctrl[grippers[0]] = 0.05 * (1.0 - action[6])
        data.ctrl[grippers[1]] = 0.05 * (1.0 - action[13])
        mujoco.mj_step(model, data, nstep=env.n_substeps)
        for cam in env.cameras:
            renderer.update_scene(data, camera=cam)
            renderer.render()
    return len(actions), time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="cup_on_plate")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--size", type=int, default=128, help="image height and width")
    args = parser.parse_args()

    world = world_config("tabletop")
    env = TabletopEnv(get_task(args.task, world), image_size=(args.size, args.size),  # all four cameras of the rig
                      robot=world_robot(world))
    poses = env.sample_initial_poses(np.random.default_rng(0))
    obs = env.reset(poses, seed=0)
    steps = run_teleop(env, make_operator(args.task, env, np.random.default_rng(0)), 150, obs)
    actions = np.stack([a for _, a in steps])

    best = {(name, clock): np.inf for name in ("ours", "bare") for clock in ("wall", "cpu")}
    n = len(actions)
    ours(env, poses, actions[:5])  # warm-up: GL context, caches
    for _ in range(args.repeats):
        for name, fn in (("ours", ours), ("bare", bare)):
            n, wall_s, cpu_s = fn(env, poses, actions)
            best[name, "wall"] = min(best[name, "wall"], wall_s / n)
            best[name, "cpu"] = min(best[name, "cpu"], cpu_s / n)
    print(f"task {args.task}, {n} control steps per episode, 4 cameras at {args.size}x{args.size}, "
          f"{env.n_substeps} physics steps per control step, best of {args.repeats}")
    # Wall clock is what a run waits for; process CPU time (all threads, the software GL's
    # included) is the steadier measure on a machine shared with other jobs.
    for clock, unit in (("wall", "wall-clock s"), ("cpu", "CPU s")):
        rate = {name: 1.0 / best[name, clock] for name in ("ours", "bare")}
        print(f"  per {unit}:")
        for name, label in (("bare", "bare mj_step + render"), ("ours", "our rollout loop")):
            print(f"    {label:24s} {rate[name]:8.1f} control steps/s  ({rate[name] * env.n_substeps:9.0f} physics steps/s)")
        print(f"    overhead of our loop: {100 * (rate['bare'] / rate['ours'] - 1.0):+.1f} %  (target <= 30 %)")
    env.close()


if __name__ == "__main__":
    main()
