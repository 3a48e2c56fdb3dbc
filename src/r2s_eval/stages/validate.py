"""Stage: agreement of one judge's ranking with the real-world reference, per checkpoint.

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
import warnings

import numpy as np
import pandas as pd

from r2s_eval.stages import _cli
from r2s_eval.stats import (
    INTERVALS,
    bootstrap_task_mean_success,
    bt_scores,
    metric_replicates,
    mmrv,
    pearson,
    percentile_interval,
    spearman,
    task_mean_success,
)
from r2s_eval.stats.checkpoints import COUPLED
from r2s_eval.utils.io import write_json
from r2s_eval.errors import DataError

RANKING = ("spearman", "pearson", "mmrv")
REFERENCE_DEFINITION = ("mean over tasks of the per-task success rate "
                        "(trials resampled within task and policy for the CI)")
METRIC_CI = ("percentile bootstrap over the fit's replicates of the chosen interval; <metric>_ci_*: judge side only "
             "(reference at its point value); <metric>_ci_*_with_reference: judge and reference replicates paired")


def _counts(reference: pd.DataFrame) -> tuple[list[str], np.ndarray, np.ndarray]:
    lacking = [c for c in ("policy", "task", "trials", "successes") if c not in reference.columns]
    if lacking:
        raise DataError(f"reference success table lacks columns {lacking}")
    grouped = reference.groupby(["policy", "task"])[["successes", "trials"]].sum()
    successes = grouped["successes"].unstack("task", fill_value=0)
    trials = grouped["trials"].unstack("task", fill_value=0)
    return [str(p) for p in successes.index], successes.to_numpy(float), trials.to_numpy(float)


def reference_rates(reference: pd.DataFrame) -> pd.Series:
    """Reference performance per policy: the mean of its per-task success rates (tasks it
    has trials on), not successes pooled over tasks."""
    policies, successes, trials = _counts(reference)
    return pd.Series(task_mean_success(successes, trials), index=pd.Index(policies, name="policy"))


def reference_bootstrap(reference: pd.DataFrame, n_boot: int, seed: int) -> pd.DataFrame:
    """(n_boot, policies) replicates of :func:`reference_rates`, trials resampled within each
    task and policy."""
    policies, successes, trials = _counts(reference)
    return pd.DataFrame(bootstrap_task_mean_success(successes, trials, n_boot, seed), columns=policies)


def _none(value) -> float | None:
    value = float(value)
    return None if math.isnan(value) else value


def validate(fit: pd.DataFrame, reference: pd.DataFrame, replicates: pd.DataFrame | None = None, *,
             level: float = 0.95, n_boot: int = 1000, seed: int = 0) -> dict:
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
        scores = group["score"].to_numpy()
        row = {
            "checkpoint": int(n),
            "spearman": spearman(scores, real),
            "pearson": pearson(scores, real),
            "mmrv": mmrv(scores, real),
            "ci_width": float(np.mean(group["ci_high"] - group["ci_low"])),
        }
        for name in INTERVALS:
            if f"ci_low_{name}" in group.columns:
                row[f"ci_width_{name}"] = float(np.mean(group[f"ci_high_{name}"] - group[f"ci_low_{name}"]))
        per_checkpoint.append(row)
    table = pd.DataFrame(per_checkpoint).sort_values("checkpoint").reset_index(drop=True)
    widths = [c for c in table.columns if c.startswith("ci_width")]
    point_metrics = list(RANKING) + widths
    average = {m: float(table[m].mean()) for m in point_metrics}

    if boot_scores is not None:
        if [int(c) for c in checkpoints] != table["checkpoint"].tolist():
            raise DataError("the replicates table and the fit table cover different checkpoints")
        for suffix, against in (("", real), ("_with_reference", ref_boot)):
            values = metric_replicates(boot_scores, against)  # {metric: (C, n_boot)}
            for m in RANKING:
                low, high = percentile_interval(values[m], level)
                table[f"{m}_ci_low{suffix}"] = low
                table[f"{m}_ci_high{suffix}"] = high
                if COUPLED.get(interval, False):
                    # Replicate b reuses the same draws at every checkpoint: its average is a
                    # replicate of the average.
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN replicates
                        low, high = percentile_interval(np.nanmean(values[m], axis=0), level)
                else:
                    low = high = float("nan")
                average[f"{m}_ci_low{suffix}"] = float(low)
                average[f"{m}_ci_high{suffix}"] = float(high)

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


def main(args) -> None:
    stats = args.cfg["stats"]
    replicates = pd.read_parquet(args.replicates) if args.replicates else None
    result = validate(pd.read_parquet(args.fit), pd.read_parquet(args.reference), replicates,
                      level=float(stats["ci_level"]), n_boot=int(stats["n_boot"]), seed=int(args.cfg["seed"]))
    write_json(args.out, result)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fit", required=True)
    p.add_argument("--replicates", help="the fit stage's bootstrap replicates (metric intervals)")
    p.add_argument("--reference", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
