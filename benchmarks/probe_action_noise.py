"""Does a trained policy survive a fraction of a degree? Its success with and without Gaussian noise
on every joint target it commands.

A real arm never sits exactly where it was told (encoders, servos, a sagging joint), and an arm
the task leaves idle then reads a state the training data never showed it. A policy trained on
exact joint states, whose normalisation divides by the idle joints' near-zero spread, reads a
fraction of a degree there as thousands of standard deviations. This probe rolls a checkpoint of
a finished run out in the run's own calibrated sim from the run's own initial configurations,
once as is and once with N(0, ``--noise``) rad added to every joint target (``--joints task``:
only the task's own arm's joints; grippers untouched), and prints both success rates with
Wilson intervals.

Run, in a finished run's working directory (the demo's, say)::

    python benchmarks/probe_action_noise.py --policy act --noise 0.006 [--arm sim] [--experiment demo]

``--arm real`` probes pi^R on the twin's side (the twin's world parameters). Writes nothing but
``--out`` (JSON), if given.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("LP_NUM_THREADS", "0")
os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from r2s_eval.config import compose_config  # noqa: E402
from r2s_eval.horizon import Horizon  # noqa: E402
from r2s_eval.paths import CONF_DIR  # noqa: E402
from r2s_eval.policies.interface import ChunkPolicy  # noqa: E402
from r2s_eval.policy_sources import open_policy  # noqa: E402
from r2s_eval.rollout.batch import EnvPool, run_batched  # noqa: E402
from r2s_eval.rollout.candidate import planned_episodes, select_inits  # noqa: E402
from r2s_eval.rollout.loop import video_frame_every  # noqa: E402
from r2s_eval.sim import load_world_params, world_robot  # noqa: E402
from r2s_eval.sim.build import make_env  # noqa: E402
from r2s_eval.sim.tasks import get_task  # noqa: E402
from r2s_eval.stats.proportions import wilson_interval  # noqa: E402


class NoisyJoints(ChunkPolicy):
    """``policy`` with N(0, sigma) added to the joint entries ``joints`` of every action it
    predicts (seeded per episode)."""

    def __init__(self, policy: ChunkPolicy, sigma: float, joints: dict[int, np.ndarray]):
        self.policy, self.sigma, self.joints = policy, float(sigma), joints
        self.spec, self.name, self.call_batch = policy.spec, policy.name, policy.call_batch
        self.observes_every_step = policy.observes_every_step
        self.rngs: dict[int, np.random.Generator] = {}

    def reset(self, slot, seed):
        self.rngs[slot] = np.random.default_rng([int(seed), 6])
        self.policy.reset(slot, seed)

    def observe(self, slot, obs):
        self.policy.observe(slot, obs)

    def release(self, slot):
        self.policy.release(slot)

    def select(self, obs):
        return self.policy.select(obs)

    def predict_chunks(self, slots, observations):
        chunks = np.array(self.policy.predict_chunks(slots, observations), dtype=np.float32)
        for row, slot in enumerate(slots):
            idx = self.joints[slot]
            chunks[row][:, idx] += self.rngs[slot].normal(0.0, self.sigma, (chunks.shape[1], len(idx)))
        return chunks

    def close(self):
        self.policy.close()


class _Discard:
    def add(self, frame):
        pass

    def abort(self):
        pass


def success_rate(run: Path, cfg: dict, policy: str, arm: str, sigma: float, joints: str, batch: int) -> dict:
    world, rollout = cfg["world"], cfg["rollout"]
    robot = world_robot(world)
    params_file = run / ("results/calib/world_params.json" if arm == "sim" else "results/real/twin_params.json")
    params = load_world_params(params_file)
    table = select_inits(pd.read_parquet(run / "results/rollout/inits.parquet"), arm, rollout.get("real_inits_per_task"))
    planned = planned_episodes(table, arm, policy, int(cfg["seed"]))
    model = open_policy(cfg["policies"][policy], policy, trained_dir=str(run / "results/train" / arm / policy),
                        device=rollout.get("device", "cpu"), call_batch=rollout["model_batch"])
    every_joint = np.concatenate([robot.slices(a)[0] for a in robot.arms])
    picked = {p.slot: (np.asarray(robot.slices(get_task(p.task, world).arm)[0]) if joints == "task" and
                       get_task(p.task, world).arm in robot.arms else every_joint) for p in planned}
    noisy = NoisyJoints(model, sigma, picked) if sigma > 0 else model
    cameras = [k.removeprefix("observation.images.") for k in model.spec.cameras]
    results = []
    try:
        run_batched(noisy, planned, EnvPool(lambda task, **shared: make_env(task, world, params, cameras=cameras, **shared)),
                    arm=arm, horizon=Horizon.from_config(rollout["horizon"]), action_map=None,
                    max_steps=robot.steps_in(rollout["max_duration_s"]), video_camera=rollout["video_camera"], video_size=None,
                    open_episode=lambda p: _Discard(),
                    on_finished=lambda p, episode, stats, sink: results.append((p.task, bool(episode.success))),
                    batch_episodes=batch, threads=1,
                    frame_every=video_frame_every(rollout["video_fps"], robot.control_dt_s))
    finally:
        noisy.close()
    outcomes = pd.DataFrame(results, columns=["task", "success"])
    k, n = int(outcomes["success"].sum()), len(outcomes)
    low, high = wilson_interval(k, n, 0.95)
    return {"noise_rad": sigma, "joints": joints, "successes": k, "episodes": n, "rate": k / n, "ci95": [low, high],
            "per_task": outcomes.groupby("task")["success"].mean().round(3).to_dict()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--run", default=".", help="a finished run's working directory")
    p.add_argument("--experiment", default="demo")
    p.add_argument("--policy", default="act")
    p.add_argument("--arm", default="sim", choices=["sim", "real"])
    p.add_argument("--noise", type=float, default=0.006, help="standard deviation (rad) of the noise on the joints")
    p.add_argument("--joints", default="all", choices=["all", "task"], help="every joint, or the task's arm's only")
    p.add_argument("--batch", type=int, default=16, help="episodes side by side")
    p.add_argument("--out", help="write both results as JSON here")
    args = p.parse_args()
    cfg = compose_config(CONF_DIR, args.experiment, [])
    rows = [success_rate(Path(args.run), cfg, args.policy, args.arm, sigma, args.joints, args.batch)
            for sigma in (0.0, args.noise)]
    for r in rows:
        print(f"{args.policy} ({args.arm}) noise {r['noise_rad']:.4f} rad on {r['joints']} joints: "
              f"{100 * r['rate']:.1f} % [{100 * r['ci95'][0]:.1f}, {100 * r['ci95'][1]:.1f}] "
              f"({r['successes']}/{r['episodes']}); per task {r['per_task']}")
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
