"""Stage: closed-loop rollouts of one candidate on one arm (sim, or the real side).

The candidate is a policy trained here, a checkpoint folder, or a policy server. The arm's world
is built with ``--world-params`` (the calibrated sim's, or the twin's); ``trained_on`` (a
cross-evaluation) names the arm whose data trained the checkpoint when it is the other one. Writes, into one
folder: episodes.parquet (one row per episode), videos/<id>.mp4 and trajectories/<id>.parquet; a
stage that dies resumes with the episodes it had not finished (``r2s_eval.rollout.candidate``).
"""

from __future__ import annotations

import json
from pathlib import Path

from r2s_eval.rollout.candidate import run_candidate
from r2s_eval.stages import _cli
from r2s_eval.utils.numerics import deterministic_torch

READS = ("rollout", "world", "seed")  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("arm", "policy", "policy_cfg", "trained_on", "tasks")  # keys the rule adds for this job


def main(args) -> None:
    # Model calls run on one thread whatever the job's threads (physics, rendering, video), so
    # their rounding never depends on them.
    deterministic_torch(1)
    cfg = args.cfg
    # Where a server or checkpoint lies, and how many episodes run side by side on how many
    # threads, reach the stage apart from its config slice: they change no result, so they must
    # not make Snakemake rerun the stage.
    run_candidate(Path(args.out), policy=cfg["policy"], arm=cfg["arm"], seed=cfg["seed"],
                  rollout=cfg["rollout"], world=cfg["world"], policy_cfg=cfg["policy_cfg"], inits=args.inits,
                  world_params=args.world_params, trained_on=cfg.get("trained_on"), trained_dir=args.policy,
                  tasks=cfg.get("tasks"), transport=json.loads(args.transport or "{}"),
                  batch_episodes=args.batch_episodes, threads=args.threads)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--policy", help="trained policy folder (candidates trained here)")
    p.add_argument("--inits", required=True)
    p.add_argument("--world-params", help="the arm's world parameters (the calibrated sim's, or the twin's)")
    p.add_argument("--transport", help="JSON: where a checkpoint or server is (path, host, port, ...)")
    p.add_argument("--batch-episodes", type=int, default=1, help="episodes stepped side by side")
    p.add_argument("--threads", type=int, default=1, help="worker threads for physics, rendering and video")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
