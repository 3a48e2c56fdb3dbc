"""Stage: fine-tune one candidate policy on one dataset (real -> pi^R, replayed sim -> pi^S).

``replicate`` k > 0 (the policy's ``seeds``) trains the same candidate again from a seed of its
own, to measure what training alone moves. ``snapshot_steps``: the steps whose weights the line-up's
snapshot candidates of this one run, saved on the way (``snapshots/<step>/``)."""

from __future__ import annotations

import pandas as pd

from r2s_eval.policies import train_policy
from r2s_eval.stages import _cli
from r2s_eval.utils.numerics import deterministic_torch

READS = ("seed",)  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("policy", "name", "replicate", "snapshot_steps")  # keys the rule adds for this job


def main(args) -> None:
    deterministic_torch(args.threads)
    policy_cfg = dict(args.cfg["policy"], name=args.cfg["name"], threads=args.threads)
    # The real arm trains only on the episodes ingest kept; the replayed sim dataset holds only those.
    episodes = None
    if args.episodes_index:
        episodes = [int(e) for e in pd.read_parquet(args.episodes_index, columns=["episode_index"])["episode_index"]]
    train_policy(args.dataset, "local/train", policy_cfg, args.out, seed=int(args.cfg["seed"]), episodes=episodes,
                 replicate=int(args.cfg.get("replicate", 0)), snapshot_steps=args.cfg.get("snapshot_steps", ()))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--episodes-index", default=None, help="ingest's index: train on its episodes only")
    p.add_argument("--out", required=True)
    p.add_argument("--threads", type=int, default=1)
    _cli.run(main, p)
