"""Stage: agreement of one judge's ranking with the real-world reference, per checkpoint."""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.stages import _cli
from r2s_eval.stats import mmrv, pearson, spearman
from r2s_eval.utils.io import write_json


def reference_rates(reference: pd.DataFrame) -> pd.Series:
    """Overall success rate per policy, pooled over tasks (trials-weighted)."""
    pooled = reference.groupby("policy")[["successes", "trials"]].sum()
    return pooled["successes"] / pooled["trials"]


def validate(fit: pd.DataFrame, reference: pd.DataFrame) -> dict:
    ref = reference_rates(reference)
    missing = sorted(set(fit["policy"]) - set(ref.index))
    if missing:
        raise ValueError(f"no reference success rate for policies {missing}")
    per_checkpoint = []
    for n, group in fit.groupby("checkpoint"):
        group = group.sort_values("policy")
        scores = group["score"].to_numpy()
        real = ref.loc[group["policy"]].to_numpy()
        per_checkpoint.append({
            "checkpoint": int(n),
            "spearman": spearman(scores, real),
            "pearson": pearson(scores, real),
            "mmrv": mmrv(scores, real),
            "ci_width": float(np.mean(group["ci_high"] - group["ci_low"])),
        })
    table = pd.DataFrame(per_checkpoint).sort_values("checkpoint")
    metrics = ["spearman", "pearson", "mmrv", "ci_width"]
    return {
        "policies": sorted(fit["policy"].unique()),
        "reference_success_rate": ref.sort_index().to_dict(),
        "per_checkpoint": table.to_dict(orient="records"),
        "average": {m: float(table[m].mean()) for m in metrics},
        "last": {m: float(table[m].iloc[-1]) for m in metrics},
    }


def main(args) -> None:
    write_json(args.out, validate(pd.read_parquet(args.fit), pd.read_parquet(args.reference)))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fit", required=True)
    p.add_argument("--reference", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
