"""Stage: agreement of one judge's ranking with the real-world reference, per checkpoint.

Spearman, Pearson and MMRV of the fit's scores against the reference (the mean of each
policy's per-task success rates), with percentile intervals from the fit's bootstrap
replicates; see ``r2s_eval.stats.validation``.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.stages import _cli
from r2s_eval.stats import validate
from r2s_eval.utils.io import write_json

READS = ("stats.ci_level", "stats.n_boot", "seed")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    replicates = pd.read_parquet(args.replicates) if args.replicates else None
    result = validate(pd.read_parquet(args.fit), pd.read_parquet(args.reference), replicates,
                      level=float(cfg["stats.ci_level"]), n_boot=int(cfg["stats.n_boot"]), seed=int(cfg["seed"]))
    write_json(args.out, result, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fit", required=True)
    p.add_argument("--replicates", help="the fit stage's bootstrap replicates (metric intervals)")
    p.add_argument("--reference", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
