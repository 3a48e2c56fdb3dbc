"""Bradley-Terry ranking quality at nested checkpoints of a comparison budget.

The paper reports each metric averaged over all checkpoints (e.g. 500, 600, ...,
2000 comparisons per policy pair) as well as its value at the last one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from r2s_eval.stats.bradley_terry import (
    bootstrap_bradley_terry,
    bt_confidence_intervals,
    bt_scores,
    fit_bradley_terry_batch,
)
from r2s_eval.stats.metrics import ci_aware_rank, mmrv, pearson, spearman

METRICS = ("ci_width", "spearman", "pearson", "mmrv")


@dataclass(frozen=True)
class CheckpointMetrics:
    """Per-checkpoint Bradley-Terry fits and ranking metrics.

    Arrays are indexed ``[checkpoint, policy]``; scores and interval bounds are on
    the 0-100 score scale ``s = 100 b``.
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


def checkpoint_metrics(
    wins,
    reference,
    n_boot: int = 1000,
    seed=0,
    *,
    level: float = 0.95,
    names: Sequence[str] | None = None,
    checkpoints: Sequence | None = None,
    n_threads: int | None = 1,
) -> CheckpointMetrics:
    """Fit, bootstrap and score the ranking at every checkpoint.

    ``wins``: ``(C, P, P)`` win counts at C nested checkpoints (a single ``(P, P)``
    matrix counts as one checkpoint); ``reference``: ``(P,)`` real-world success
    rates.  Per checkpoint: point strengths, scores, percentile intervals from
    ``n_boot`` replicates (one vectorised bootstrap over all checkpoints), the mean
    interval width and Spearman, Pearson and MMRV of the scores against
    ``reference`` (MMRV in the units of ``reference``).  ``average`` is the mean
    over checkpoints, ``last`` the final checkpoint.  ``n_threads``: see
    :func:`bootstrap_bradley_terry` (``None`` uses all CPUs; same result).
    """
    arr = np.asarray(wins, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"wins must have shape (C, P, P) or (P, P), got {arr.shape}")
    C, P = arr.shape[0], arr.shape[-1]
    ref = np.asarray(reference, dtype=np.float64)
    if ref.shape != (P,):
        raise ValueError(f"reference must have one value per policy ({P}), got shape {ref.shape}")
    names = [f"policy_{i}" for i in range(P)] if names is None else [str(n) for n in names]
    if len(names) != P:
        raise ValueError(f"names has {len(names)} entries for {P} policies")
    labels = np.arange(C) if checkpoints is None else np.asarray(checkpoints)
    if labels.shape != (C,):
        raise ValueError(f"checkpoints must have {C} labels, got shape {labels.shape}")

    strengths = fit_bradley_terry_batch(arr, names=names)
    boot = bootstrap_bradley_terry(arr, n_boot=n_boot, seed=seed, names=names, n_threads=n_threads)
    lower, upper = bt_confidence_intervals(boot, level)
    scores = bt_scores(strengths)
    per_checkpoint = pd.DataFrame(
        {
            "ci_width": (upper - lower).mean(axis=1),
            "spearman": [spearman(s, ref) for s in scores],
            "pearson": [pearson(s, ref) for s in scores],
            "mmrv": [mmrv(s, ref) for s in scores],
        },
        index=pd.Index(labels, name="checkpoint"),
    )
    return CheckpointMetrics(
        checkpoints=labels,
        names=names,
        strengths=strengths,
        scores=scores,
        ci_lower=lower,
        ci_upper=upper,
        boot_strengths=boot,
        per_checkpoint=per_checkpoint,
        average=per_checkpoint.mean(axis=0).rename("average"),
        last=per_checkpoint.iloc[-1].rename("last"),
    )
