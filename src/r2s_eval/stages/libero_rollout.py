"""Stage: closed-loop LIBERO rollouts of one candidate (a checkpoint or a policy server).

Writes the same folder as our own world's rollouts (episodes.parquet, videos/, trajectories/),
so the judges, the pairs, the fit and the reports read it unchanged; episodes finished before a
crash are kept and a rerun does the rest (``r2s_eval.libero.rollout``).
"""

from __future__ import annotations

import json
from pathlib import Path

from r2s_eval.libero.rollout import run_libero_candidate
from r2s_eval.stages import _cli
from r2s_eval.utils.numerics import deterministic_torch

READS = ("libero", "rollout.horizon", "rollout.device", "seed")  # see _reads.py
PROVIDED = ("policy", "policy_cfg")  # keys the rule adds for this job


def main(args) -> None:
    deterministic_torch(1)  # model calls on one thread: their rounding never depends on the job's threads
    cfg = args.cfg
    rollout = {"horizon": cfg["rollout.horizon"], "device": cfg["rollout.device"]}
    run_libero_candidate(Path(args.out), policy=cfg["policy"], seed=cfg["seed"], libero=cfg["libero"], rollout=rollout,
                         policy_cfg=cfg["policy_cfg"], python=Path(args.python),
                         transport=json.loads(args.transport or "{}"), workers=args.threads,
                         world_log=Path(args.log).with_suffix(".libero.log") if args.log else None)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--python", required=True, help="the interpreter of LIBERO's own environment")
    p.add_argument("--transport", help="JSON: where the checkpoint or server is (path, host, port, ...)")
    p.add_argument("--threads", type=int, default=1, help="LIBERO processes side by side")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
