"""The real-world reference performance of each policy, with a bootstrap interval.

The method defines a policy's reference performance as the mean of its per-task success
rates (every task weighs the same, whatever its number of trials), not as successes
pooled over tasks.  Its bootstrap resamples the trials within each task and policy: a
replicate's per-task rate is ``Binomial(trials, successes / trials) / trials`` (drawing
``trials`` outcomes with replacement from the recorded ones), and the replicate's
reference is the mean of those rates.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.stats.bradley_terry import _check_n_boot
from r2s_eval.stats.units import tagged_seed

REFERENCE_KEY = 0x72656673  # spawn-key tag of the reference bootstrap's stream ("refs")


def _counts(successes, trials) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(successes, dtype=np.float64)
    n = np.asarray(trials, dtype=np.float64)
    if s.ndim != 2 or s.shape != n.shape:
        raise DataError(f"successes and trials must both be (policies, tasks), got {s.shape} and {n.shape}")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(n))) or np.any(n < 0) or np.any(s < 0) or np.any(s > n):
        raise DataError("need 0 <= successes <= trials, all finite")
    if np.any(n != np.round(n)) or np.any(s != np.round(s)):
        raise DataError("successes and trials must be whole numbers")
    empty = np.flatnonzero((n > 0).sum(axis=1) == 0)
    if empty.size:
        raise DataError(f"policies {empty.tolist()} have no trials on any task")
    return s, n


def task_mean_success(successes, trials) -> np.ndarray:
    """Mean over tasks of the per-task success rate, per policy: ``(P,)``.

    ``successes``, ``trials``: ``(P, T)`` counts per policy and task; a task with no trials
    for a policy (``trials == 0``) is left out of that policy's mean.
    """
    s, n = _counts(successes, trials)
    rates = np.divide(s, n, out=np.full_like(s, np.nan), where=n > 0)
    return np.nanmean(rates, axis=1)


def bootstrap_task_mean_success(successes, trials, n_boot: int, seed=0) -> np.ndarray:
    """Bootstrap replicates of :func:`task_mean_success`: ``(n_boot, P)``.

    Trials are resampled within each task and policy (binomially, see the module
    docstring).  Deterministic for a given ``seed``: draws come from
    ``SeedSequence(seed)``'s child with spawn key ``(REFERENCE_KEY,)``, so the same config
    seed gives streams unrelated to the Bradley-Terry bootstraps'.
    """
    n_boot = _check_n_boot(n_boot)
    s, n = _counts(successes, trials)
    have = n > 0
    p = np.divide(s, n, out=np.zeros_like(s), where=have)
    rng = np.random.default_rng(tagged_seed(seed, REFERENCE_KEY))
    draws = rng.binomial(n.astype(np.int64), p, size=(n_boot,) + s.shape).astype(np.float64)
    rates = np.divide(draws, n, out=np.full_like(draws, np.nan), where=have)
    return np.nanmean(rates, axis=2)


def _table_counts(reference: pd.DataFrame) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Policies and their ``(P, T)`` success and trial counts from a reference success table
    (columns policy, task, trials, successes; rows of one policy and task add up)."""
    lacking = [c for c in ("policy", "task", "trials", "successes") if c not in reference.columns]
    if lacking:
        raise DataError(f"reference success table lacks columns {lacking}")
    grouped = reference.groupby(["policy", "task"])[["successes", "trials"]].sum()
    successes = grouped["successes"].unstack("task", fill_value=0)
    trials = grouped["trials"].unstack("task", fill_value=0)
    return [str(p) for p in successes.index], successes.to_numpy(float), trials.to_numpy(float)


def reference_rates(reference: pd.DataFrame) -> pd.Series:
    """Reference performance per policy from a reference success table: the mean of its
    per-task success rates (tasks it has trials on), not successes pooled over tasks."""
    policies, successes, trials = _table_counts(reference)
    return pd.Series(task_mean_success(successes, trials), index=pd.Index(policies, name="policy"))


def reference_bootstrap(reference: pd.DataFrame, n_boot: int, seed) -> pd.DataFrame:
    """(n_boot, policies) replicates of :func:`reference_rates`, trials resampled within each
    task and policy."""
    policies, successes, trials = _table_counts(reference)
    return pd.DataFrame(bootstrap_task_mean_success(successes, trials, n_boot, seed), columns=policies)
