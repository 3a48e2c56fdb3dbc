"""LIBERO closed-loop steps per second: rendering on demand vs LIBERO's default rendering.

Both loops are `r2s_eval/libero/libero_side.py` in LIBERO's own environment, talking to our policy
server on loopback, on the same task, initial states and actions: the policy reads two cameras
(agent view and wrist) at its query steps (every 5th step), the judge video records the agent
view at 5 fps (every 4th step), all at 224x224.

- default: LIBERO's own rendering, every camera at every step, with its default quality
  (multisampling, shadow map); the consumed images are taken from its observations.
- on_demand (ours): nothing rendered at a step unless the policy or the video uses it, no
  multisampling, no shadow map.

The policy is a cheap scripted one (a slow sweep of the end effector), so the numbers are the
world's. Repeats interleave the two modes so machine load hits both alike; the best repeat of
each is reported (steps per second of episode time, environment creation excluded).

Run: ``python benchmarks/bench_libero_render.py [--episodes 2] [--steps 100] [--repeats 2]``
(makes LIBERO's environment first if it is not there: a few minutes).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import yaml

from r2s_eval.horizon import Horizon
from r2s_eval.libero import environment, selected_tasks
from r2s_eval.libero.rollout import planned_episodes, run_world_processes, world_job
from r2s_eval.policies.interface import ChunkPolicy, PolicySpec
from r2s_eval.serving.policy_server import PolicyServer

CAMERAS = {"image": "agentview", "wrist_image": "robot0_eye_in_hand"}
# The evaluation's receding horizon, as the workflow configures it.
HORIZON = Horizon.from_config(
    yaml.safe_load((Path(__file__).resolve().parents[1] / "conf" / "rollout" / "default.yaml").read_text())["horizon"])


class Sweep(ChunkPolicy):
    """A slow sinusoidal sweep of the end effector, gripper open: costs nothing to compute."""

    name = "sweep"
    spec = PolicySpec(cameras=tuple(f"observation.images.{k}" for k in CAMERAS), action_dim=7, max_chunk=25, state_dim=8)

    def predict_chunks(self, slots, observations):
        t = np.arange(25)[:, None] / 25.0
        chunk = np.zeros((25, 7), np.float32)
        chunk[:, :3] = 0.3 * np.sin(2 * np.pi * t + np.arange(3))
        chunk[:, 6] = -1.0
        return np.repeat(chunk[None], len(slots), axis=0)


def run(mode: str, python: Path, port: int, episodes: int, steps: int, work: Path) -> tuple[int, float]:
    tasks = selected_tasks(["libero_spatial_0"], {"libero_spatial": steps})
    libero = {"observation": {"image_size": [224, 224], "rotate_180": True}, "settle_steps": 10, "render": mode,
              "video": {"camera": "agentview", "size": [224, 224], "fps": 5}}
    job = world_job(libero, HORIZON, {f"observation.images.{k}": c for k, c in CAMERAS.items()},
                    planned_episodes(tasks, episodes, seed=0, policy="sweep"), {t.name: t for t in tasks}, port,
                    work / mode)
    records = []
    work.mkdir(parents=True, exist_ok=True)

    def keep(npz: Path) -> None:
        with np.load(npz) as r:
            records.append((len(r["action"]), float(r["wall_s"])))
        npz.unlink()

    failures = run_world_processes(python, [job], work, keep, work / "world.log")
    if failures:
        raise SystemExit(f"{mode}: {failures} (see {work / 'world.log'})")
    return sum(n for n, _ in records), sum(s for _, s in records)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=2)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=2)
    args = p.parse_args()
    python = environment.ensure(environment.env_dir(None))
    server = PolicyServer(Sweep(), port=0)
    port = server.start()
    best: dict[str, float] = {}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(args.repeats):
                for mode in ("default", "on_demand"):
                    n, seconds = run(mode, python, port, args.episodes, args.steps, Path(tmp) / f"r{r}")
                    rate = n / seconds
                    best[mode] = max(best.get(mode, 0.0), rate)
                    print(f"repeat {r} {mode:9s}: {n} steps in {seconds:.1f} s = {rate:.2f} steps/s", flush=True)
    finally:
        server.stop()
    print(json.dumps({"default_steps_per_s": round(best["default"], 2),
                      "on_demand_steps_per_s": round(best["on_demand"], 2),
                      "ratio": round(best["on_demand"] / best["default"], 2)}))
    print(f"LIBERO closed loop with policy cameras and judge video: {best['on_demand']:.2f} steps/s on demand, "
          f"{best['default']:.2f} steps/s with LIBERO's default rendering: {best['on_demand'] / best['default']:.2f}x")


if __name__ == "__main__":
    main()
