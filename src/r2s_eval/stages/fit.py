"""Stage: Bradley-Terry strengths and bootstrap CIs for one judge at every nested checkpoint.

Writes the fit table (both bootstraps' intervals, ``binomial`` and ``unit``; ``ci_low``/``ci_high``
repeat the one ``stats.interval`` names) and, with ``--replicates``, the bootstrap replicates for
the validate stage; see ``r2s_eval.stats.fit_table``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.compare import checkpoint_sizes
from r2s_eval.stages import _cli
from r2s_eval.stats import fit_checkpoints
from r2s_eval.utils.io import read_parquet_metadata, write_parquet

READS = ("stats.n_boot", "stats.ci_level", "stats.interval", "compare.checkpoints", "seed")  # config paths the --cfg slice holds (see _reads.py)
# The adaptive judging's account the fit passes on to the report (r2s_eval.judge.adaptive).
ADAPTIVE_SUMMARY = ("alpha", "stop", "rounds", "items", "calls", "requests", "describe_calls", "describe_requests",
                    "undecided", "pairs")


def main(args) -> None:
    cfg = args.cfg
    n_boot, ci_level = int(cfg["stats.n_boot"]), float(cfg["stats.ci_level"])
    verdicts = pd.read_parquet(args.verdicts)
    pairs = pd.read_parquet(args.pairs) if args.pairs else None
    table, replicates = fit_checkpoints(
        verdicts, checkpoint_sizes(cfg["compare.checkpoints"]), n_boot, ci_level, int(cfg["seed"]),
        interval=str(cfg["stats.interval"]), pairs=pairs,
    )
    a_share = float(np.mean(verdicts["verdict"] == "A"))
    meta = {"stage": "fit", "share_of_A_answers": a_share, "interval": str(table["interval"].iloc[0]),
            "ci_level": ci_level, "n_boot": n_boot}
    judged = read_parquet_metadata(args.verdicts).get("stats", {})
    if judged.get("allocation") == "adaptive":  # what the ranking rests on, for the report
        meta["adaptive"] = {k: judged.get(k) for k in ADAPTIVE_SUMMARY}
    write_parquet(args.out, table, metadata=meta)
    if args.replicates:
        write_parquet(args.replicates, replicates, metadata=meta)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--verdicts", required=True)
    p.add_argument("--pairs", help="sampled pairs (results/compare/pairs.parquet): each comparison's task and init")
    p.add_argument("--out", required=True)
    p.add_argument("--replicates", help="bootstrap replicates of every interval, for the validate stage")
    _cli.run(main, p)
