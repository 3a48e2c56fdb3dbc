"""Stage: agreement of one judge's ranking with the real-world reference, per checkpoint.

Spearman, Pearson and MMRV of the fit's scores against the reference (the mean of each
policy's per-task success rates), with percentile intervals from the fit's bootstrap
replicates; see ``r2s_eval.stats.validation``. With the checkpoints the sim ranks (pi^S) also
rolled out in the twin (``stability.networks_in_twin``: ``--networks-in-twin``), the same metrics
against their success there too (``against_networks_in_twin``, the candidates trained here): the
real reference is pi^R's, another checkpoint per candidate, so where the two part, the order is
the training data's, not the sim's or the judge's.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.stages import _cli
from r2s_eval.stats import validate
from r2s_eval.stats.reference_table import reference_table
from r2s_eval.utils.io import write_json

READS = ("stats.ci_level", "stats.n_boot", "seed")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    replicates = pd.read_parquet(args.replicates) if args.replicates else None
    fit = pd.read_parquet(args.fit)
    stats = dict(level=float(cfg["stats.ci_level"]), n_boot=int(cfg["stats.n_boot"]), seed=int(cfg["seed"]))
    result = validate(fit, pd.read_parquet(args.reference), replicates, **stats)
    if args.networks_in_twin:
        networks = reference_table(rollout_dirs=args.networks_in_twin)
        crossed = set(networks["policy"])
        result["against_networks_in_twin"] = validate(
            fit[fit["policy"].isin(crossed)], networks,
            None if replicates is None else replicates[replicates["policy"].isin(crossed)], **stats)
    write_json(args.out, result, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fit", required=True)
    p.add_argument("--replicates", help="the fit stage's bootstrap replicates (metric intervals)")
    p.add_argument("--reference", required=True)
    p.add_argument("--networks-in-twin", nargs="*", default=[],
                   help="the judged checkpoints' rollouts in the twin (results/cross/real/<policy>), one per policy")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
