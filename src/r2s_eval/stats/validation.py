"""Agreement of one judge's fitted ranking with the real-world reference, per checkpoint.

The reference performance of a policy is the mean of its per-task success rates, with a
bootstrap interval (trials resampled within each task and policy). Spearman, Pearson and
MMRV get percentile intervals from the fit's bootstrap replicates (the interval that
``stats.interval`` names): ``<metric>_ci_low/_ci_high`` hold the reference at its point
value, so they carry the judge side's uncertainty only; ``<metric>_ci_low_with_reference/
_ci_high_with_reference`` pair each judge replicate with an independent reference replicate,
so they carry both.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.stats.bradley_terry import bt_scores
from r2s_eval.stats.checkpoints import COUPLED, INTERVALS, metric_ci_tables, percentile_interval, ranking_metrics
from r2s_eval.stats.metrics import RANKING_METRICS
from r2s_eval.stats.reference import reference_bootstrap, reference_rates

REFERENCE_DEFINITION = ("mean over tasks of the per-task success rate "
                        "(trials resampled within task and policy for the CI)")
METRIC_CI = ("percentile bootstrap over the fit's replicates of the chosen interval; <metric>_ci_*: judge side only "
             "(reference at its point value); <metric>_ci_*_with_reference: judge and reference replicates paired")


def _none(value) -> float | None:
    value = float(value)
    return None if math.isnan(value) else value


def _ci_name(column: str) -> str:
    """``spearman_low_with_reference`` (``metric_ci_tables``) -> ``spearman_ci_low_with_reference``."""
    metric, rest = column.split("_", 1)
    return f"{metric}_ci_{rest}"


def validate(fit: pd.DataFrame, reference: pd.DataFrame, replicates: pd.DataFrame | None = None, *,
             level: float, n_boot: int, seed: int) -> dict:
    """Per checkpoint: Spearman, Pearson, MMRV against the reference and the mean score-interval
    width of each bootstrap; with the fit's ``replicates``, percentile intervals of the three
    metrics. The reference's own interval uses as many replicates as the fit (``n_boot``
    without replicates)."""
    ref = reference_rates(reference)
    missing = sorted(set(fit["policy"]) - set(ref.index))
    if missing:
        raise DataError(f"no reference success rate for policies {missing}")
    policies = sorted(fit["policy"].unique())
    interval = str(fit["interval"].iloc[0]) if "interval" in fit.columns else "binomial"
    real = ref.loc[policies].to_numpy()

    boot_scores = None
    if replicates is not None:
        mine = replicates[replicates["interval"] == interval]
        if mine.empty:
            raise DataError(f"the replicates table has no {interval!r} replicates")
        wide = mine.pivot(index=["checkpoint", "replicate"], columns="policy", values="strength")
        wide = wide.sort_index()[policies]
        checkpoints = sorted(wide.index.get_level_values("checkpoint").unique())
        n_boot = wide.index.get_level_values("replicate").nunique()  # pair replicate b with reference b
        boot_scores = bt_scores(wide.to_numpy().reshape(len(checkpoints), n_boot, len(policies)))
    ref_boot = reference_bootstrap(reference, n_boot, seed)[policies].to_numpy()
    ref_low, ref_high = percentile_interval(ref_boot, level, axis=0)

    per_checkpoint = []
    for n, group in fit.groupby("checkpoint"):
        group = group.set_index("policy").loc[policies]
        row = {"checkpoint": int(n), **ranking_metrics(group["score"].to_numpy(), real),
               "ci_width": float(np.mean(group["ci_high"] - group["ci_low"]))}
        for name in INTERVALS:
            if f"ci_low_{name}" in group.columns:
                row[f"ci_width_{name}"] = float(np.mean(group[f"ci_high_{name}"] - group[f"ci_low_{name}"]))
        per_checkpoint.append(row)
    table = pd.DataFrame(per_checkpoint).sort_values("checkpoint").reset_index(drop=True)
    widths = [c for c in table.columns if c.startswith("ci_width")]
    average = {m: float(table[m].mean()) for m in [*RANKING_METRICS, *widths]}

    if boot_scores is not None:
        if [int(c) for c in checkpoints] != table["checkpoint"].tolist():
            raise DataError("the replicates table and the fit table cover different checkpoints")
        # Replicate b of a coupled interval reuses the same draws at every checkpoint: its
        # average is a replicate of the average.
        metric_ci, average_ci = metric_ci_tables(boot_scores, real, ref_boot, level, checkpoints,
                                                 COUPLED.get(interval, False))
        for column in metric_ci.columns:
            table[_ci_name(column)] = metric_ci[column].to_numpy()
        average.update({_ci_name(k): float(v) for k, v in average_ci.items()})

    records = [{k: (int(v) if k == "checkpoint" else _none(v)) for k, v in r.items()} for r in table.to_dict("records")]
    return {
        "policies": policies,
        "interval": interval,
        "ci_level": level,
        "metric_ci": METRIC_CI,
        "reference": {
            "definition": REFERENCE_DEFINITION,
            "success_rate": dict(zip(policies, map(float, real))),
            "ci_low": dict(zip(policies, map(_none, ref_low))),
            "ci_high": dict(zip(policies, map(_none, ref_high))),
            "n_boot": int(ref_boot.shape[0]),
        },
        "reference_success_rate": dict(zip(policies, map(float, real))),
        "per_checkpoint": records,
        "average": {k: _none(v) for k, v in average.items()},
        "last": {k: v for k, v in records[-1].items() if k != "checkpoint"},
    }
