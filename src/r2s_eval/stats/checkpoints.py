"""Bradley-Terry ranking quality at nested checkpoints of a comparison budget.

The paper reports each metric averaged over all checkpoints (e.g. 500, 600, ...,
2000 comparisons per policy pair) as well as its value at the last one.  Two bootstraps
give the score intervals: ``binomial`` (the method's: every comparison redrawn
independently, :func:`~r2s_eval.stats.bootstrap_bradley_terry`) and ``unit`` (the
distinct task/init rollout pairs resampled within each task,
:func:`~r2s_eval.stats.unit_bootstrap_bradley_terry`); the ranking metrics get percentile
intervals from the chosen bootstrap's replicates.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from r2s_eval.errors import ConfigError, StatsError
from r2s_eval.stats.bradley_terry import (
    bootstrap_bradley_terry,
    bt_confidence_intervals,
    bt_scores,
    fit_bradley_terry_batch,
)
from r2s_eval.stats.metrics import RANKING_METRICS, ci_aware_rank, mmrv, pearson, spearman
from r2s_eval.stats.units import ComparisonUnits, unit_bootstrap_bradley_terry

METRICS = ("ci_width", "spearman", "pearson", "mmrv")
INTERVALS = ("unit", "binomial")
# Whether replicate b at different checkpoints comes from the same draws, so that an
# average over checkpoints per replicate has a bootstrap distribution.
COUPLED = {"unit": True, "binomial": False}


def check_interval(interval: str) -> str:
    if interval not in INTERVALS:
        raise ConfigError(f"interval must be one of {list(INTERVALS)}, got {interval!r}")
    return interval


def percentile_interval(values, level: float, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles along ``axis``, ignoring NaN
    replicates (a metric undefined on a replicate, e.g. a constant ranking); NaN where
    every replicate is NaN."""
    if not 0.0 < level < 1.0:
        raise ConfigError(f"level must lie strictly between 0 and 1, got {level}")
    tail = 50.0 * (1.0 - level)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices
        lower, upper = np.nanpercentile(np.asarray(values, dtype=np.float64), [tail, 100.0 - tail], axis=axis)
    return lower, upper


def metric_replicates(boot_scores, reference) -> dict[str, np.ndarray]:
    """Spearman, Pearson and MMRV of every bootstrap replicate: ``{metric: (..., n_boot)}``.

    ``boot_scores``: ``(..., n_boot, P)`` replicate scores; ``reference``: ``(P,)`` (held
    fixed: only the score side varies) or ``(n_boot, P)`` replicates of the reference,
    paired with the score replicates one to one (both sides vary, independently).
    """
    return {name: fn(boot_scores, reference) for name, fn in RANKING_METRICS.items()}


def metric_intervals(boot_scores, reference, level: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Percentile intervals of the ranking metrics from :func:`metric_replicates`:
    ``{metric: (lower, upper)}``, each ``(...)``."""
    return {name: percentile_interval(v, level) for name, v in metric_replicates(boot_scores, reference).items()}


@dataclass(frozen=True)
class CheckpointMetrics:
    """Per-checkpoint Bradley-Terry fits and ranking metrics.

    Arrays are indexed ``[checkpoint, policy]``; scores and interval bounds are on
    the 0-100 score scale ``s = 100 b``.  ``ci_lower``/``ci_upper``/``boot_strengths``
    belong to the chosen ``interval``; ``ci_by_interval`` and ``boot_by_interval`` hold
    every bootstrap that was run.
    """

    checkpoints: np.ndarray  # (C,) labels, e.g. comparisons per pair
    names: list[str]  # (P,) policy names
    strengths: np.ndarray  # (C, P) point estimates, each row sums to 1
    scores: np.ndarray  # (C, P)
    ci_lower: np.ndarray  # (C, P) percentile bootstrap interval of the score
    ci_upper: np.ndarray  # (C, P)
    boot_strengths: np.ndarray  # (C, n_boot, P)
    per_checkpoint: pd.DataFrame  # index: checkpoint; columns: METRICS
    average: pd.Series  # mean of each metric over checkpoints (what the paper reports)
    last: pd.Series  # each metric at the last checkpoint
    interval: str = "binomial"
    ci_by_interval: Mapping[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    boot_by_interval: Mapping[str, np.ndarray] = field(default_factory=dict)
    # index: checkpoint; columns <metric>_low/_high (score side only) and, with reference
    # replicates, <metric>_low_with_reference/_high_with_reference (both sides).
    metric_ci: pd.DataFrame | None = None
    # The same for the average over checkpoints; NaN unless the interval is coupled.
    average_ci: pd.Series | None = None
    ci_width_by_interval: pd.DataFrame | None = None  # index: checkpoint; columns: intervals

    def policy_table(self) -> pd.DataFrame:
        """Long table: one row per (checkpoint, policy) with its fit and CI-aware rank."""
        rows = []
        for c, label in enumerate(self.checkpoints):
            ranks = ci_aware_rank(self.ci_lower[c], self.ci_upper[c])
            for i, name in enumerate(self.names):
                rows.append(
                    {
                        "checkpoint": label,
                        "policy": name,
                        "strength": self.strengths[c, i],
                        "score": self.scores[c, i],
                        "ci_lower": self.ci_lower[c, i],
                        "ci_upper": self.ci_upper[c, i],
                        "ci_aware_rank": int(ranks[i]),
                    }
                )
        return pd.DataFrame(rows)


def ranking_metrics(scores, reference) -> dict[str, float]:
    """Spearman, Pearson and MMRV of one checkpoint's ``(P,)`` scores against ``reference``."""
    return {"spearman": spearman(scores, reference), "pearson": pearson(scores, reference),
            "mmrv": mmrv(scores, reference)}


def bootstrap_checkpoints(
    wins, units: ComparisonUnits | None, n_boot: int, seed, names, level: float, n_threads: int | None = 1
) -> tuple[dict[str, np.ndarray], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Every bootstrap that applies, over all checkpoints in one pass each: ``binomial`` on
    ``wins`` ``(C, P, P)`` and, with ``units``, ``unit``.  Returns the replicate strengths
    ``{interval: (C, n_boot, P)}`` and their percentile score intervals ``{interval: (lower,
    upper)}``, each ``(C, P)``."""
    boots = {"binomial": bootstrap_bradley_terry(wins, n_boot=n_boot, seed=seed, names=names, n_threads=n_threads)}
    if units is not None:
        boots["unit"] = unit_bootstrap_bradley_terry(units, n_boot=n_boot, seed=seed, names=names, n_threads=n_threads)
    return boots, {name: bt_confidence_intervals(boot, level) for name, boot in boots.items()}


def metric_ci_tables(boot_scores, ref, reference_boot, level, labels, coupled) -> tuple[pd.DataFrame, pd.Series]:
    """Percentile intervals of the ranking metrics per checkpoint and of their average.

    ``boot_scores``: ``(C, n_boot, P)`` replicate scores; ``ref``: ``(P,)``;
    ``reference_boot``: ``None`` or ``(n_boot, P)`` reference replicates.  Returns a table
    indexed by ``labels`` with columns ``<metric>_low/_high`` (score side only) and, with
    ``reference_boot``, ``<metric>_low_with_reference/_high_with_reference`` (both sides
    vary), and the same for the average over checkpoints (NaN unless ``coupled``: replicate
    ``b`` reuses the same draws at every checkpoint)."""
    sides = {"": ref}
    if reference_boot is not None:
        sides["_with_reference"] = reference_boot
    per_checkpoint, average = {}, {}
    for suffix, reference in sides.items():
        for name, values in metric_replicates(boot_scores, reference).items():  # (C, n_boot)
            low, high = percentile_interval(values, level)
            per_checkpoint[f"{name}_low{suffix}"] = low
            per_checkpoint[f"{name}_high{suffix}"] = high
            if coupled:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    low, high = percentile_interval(np.nanmean(values, axis=0), level)
            else:
                low = high = float("nan")
            average[f"{name}_low{suffix}"] = float(low)
            average[f"{name}_high{suffix}"] = float(high)
    table = pd.DataFrame(per_checkpoint, index=pd.Index(labels, name="checkpoint"))
    return table, pd.Series(average, name="average")


def checkpoint_metrics(
    wins,
    reference,
    n_boot: int,
    seed=0,
    *,
    level: float,
    names: Sequence[str] | None = None,
    checkpoints: Sequence | None = None,
    n_threads: int | None = 1,
    interval: str | None = None,
    reference_boot=None,
) -> CheckpointMetrics:
    """Fit, bootstrap and score the ranking at every checkpoint.

    ``wins``: ``(C, P, P)`` win counts at C nested checkpoints (a single ``(P, P)``
    matrix counts as one checkpoint), or a :class:`~r2s_eval.stats.ComparisonUnits`
    (which also allows the unit bootstrap); ``reference``: ``(P,)`` real-world success
    rates.  Per checkpoint: point strengths, scores, percentile intervals from
    ``n_boot`` replicates of each bootstrap (one vectorised pass over all checkpoints),
    the mean interval width and Spearman, Pearson and MMRV of the scores against
    ``reference`` (MMRV in the units of ``reference``), with percentile intervals from the
    chosen bootstrap's replicates (``metric_ci``).  ``interval``: which bootstrap the
    intervals and ``ci_width`` belong to, ``"unit"`` (the default with units) or
    ``"binomial"`` (the only one for plain win counts).  ``reference_boot``: optional
    ``(n_boot, P)`` replicates of the reference, paired with the score replicates for
    intervals that include the reference's own uncertainty.  ``average`` is the mean
    over checkpoints, ``last`` the final checkpoint.  ``n_threads``: see
    :func:`bootstrap_bradley_terry` (``None`` uses all CPUs; same result).
    """
    units = wins if isinstance(wins, ComparisonUnits) else None
    arr = units.wins() if units is not None else np.asarray(wins, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"wins must have shape (C, P, P) or (P, P), got {arr.shape}")
    interval = check_interval(interval or ("unit" if units is not None else "binomial"))
    if interval == "unit" and units is None:
        raise ConfigError("the unit bootstrap needs ComparisonUnits (which comparisons share a rollout pair)")
    C, P = arr.shape[0], arr.shape[-1]
    ref = np.asarray(reference, dtype=np.float64)
    if ref.shape != (P,):
        raise StatsError(f"reference must have one value per policy ({P}), got shape {ref.shape}")
    if reference_boot is not None:
        reference_boot = np.asarray(reference_boot, dtype=np.float64)
        if reference_boot.shape != (n_boot, P):
            raise StatsError(f"reference_boot must have shape ({n_boot}, {P}), got {reference_boot.shape}")
    names = [f"policy_{i}" for i in range(P)] if names is None else [str(n) for n in names]
    if len(names) != P:
        raise StatsError(f"names has {len(names)} entries for {P} policies")
    if checkpoints is None:
        labels = np.asarray(units.checkpoints) if units is not None else np.arange(C)
    else:
        labels = np.asarray(checkpoints)
    if labels.shape != (C,):
        raise ValueError(f"checkpoints must have {C} labels, got shape {labels.shape}")

    strengths = fit_bradley_terry_batch(arr, names=names)
    boots, cis = bootstrap_checkpoints(arr, units, n_boot, seed, names, level, n_threads)
    lower, upper = cis[interval]
    scores = bt_scores(strengths)
    index = pd.Index(labels, name="checkpoint")
    ranking = [ranking_metrics(s, ref) for s in scores]
    per_checkpoint = pd.DataFrame(
        {"ci_width": (upper - lower).mean(axis=1), **{m: [r[m] for r in ranking] for m in RANKING_METRICS}},
        index=index,
    )
    metric_ci, average_ci = metric_ci_tables(
        bt_scores(boots[interval]), ref, reference_boot, level, labels, COUPLED[interval]
    )
    widths = pd.DataFrame({name: (hi - lo).mean(axis=1) for name, (lo, hi) in cis.items()}, index=index)
    return CheckpointMetrics(
        checkpoints=labels,
        names=names,
        strengths=strengths,
        scores=scores,
        ci_lower=lower,
        ci_upper=upper,
        boot_strengths=boots[interval],
        per_checkpoint=per_checkpoint,
        average=per_checkpoint.mean(axis=0).rename("average"),
        last=per_checkpoint.iloc[-1].rename("last"),
        interval=interval,
        ci_by_interval=cis,
        boot_by_interval=boots,
        metric_ci=metric_ci,
        average_ci=average_ci,
        ci_width_by_interval=widths,
    )
