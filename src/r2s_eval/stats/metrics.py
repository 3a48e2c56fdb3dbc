"""Agreement metrics: ranking quality against a reference, and judge consistency.

Ranking metrics take ``scores`` first (the simulator / judge side, e.g. Bradley-Terry
scores) and ``reference`` second (real-world success rates).  Correlations are
symmetric; MMRV is not: it sizes each violation by the *reference* margin.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import NamedTuple

import numpy as np
from scipy import stats

from r2s_eval.errors import DataError, StatsError


def _paired(scores, reference) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(scores, dtype=np.float64)
    y = np.asarray(reference, dtype=np.float64)
    if x.ndim != 1 or y.ndim != 1:
        raise ValueError(f"scores and reference must be 1-D, got shapes {x.shape} and {y.shape}")
    if x.shape != y.shape:
        raise StatsError(f"scores has {x.size} policies but reference has {y.size}")
    if x.size < 2:
        raise StatsError("a ranking metric needs at least 2 policies")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise StatsError("scores and reference must be finite")
    return x, y


def spearman(scores, reference) -> float:
    """Spearman rank correlation; ties get average ranks.

    Returns NaN when either input is constant (the correlation is undefined).
    """
    x, y = _paired(scores, reference)
    if np.all(x == x[0]) or np.all(y == y[0]):
        return float("nan")
    return float(stats.spearmanr(x, y).statistic)


def pearson(scores, reference) -> float:
    """Pearson correlation.  Returns NaN when either input is constant."""
    x, y = _paired(scores, reference)
    if np.all(x == x[0]) or np.all(y == y[0]):
        return float("nan")
    return float(stats.pearsonr(x, y).statistic)


def mmrv(scores, reference) -> float:
    """Mean Maximum Rank Violation, as defined with SimplerEnv.

    For each policy ``i``: the largest reference margin ``|reference[i] -
    reference[j]|`` over the policies ``j`` whose order disagrees, i.e.
    ``(scores[i] > scores[j]) != (reference[i] > reference[j])`` (strict
    comparisons, so a tie on one side against a strict order on the other counts),
    or 0 if there is none; then the mean over policies.  The result is in the units
    of ``reference``.  Not symmetric: swapping the arguments sizes violations by the
    other vector's margins.
    """
    x, y = _paired(scores, reference)
    disagree = (x[:, None] > x[None, :]) != (y[:, None] > y[None, :])
    margins = np.where(disagree, np.abs(y[:, None] - y[None, :]), 0.0)
    return float(margins.max(axis=1).mean())


def ci_aware_rank(lower, upper) -> np.ndarray:
    """Rank that only separates policies whose intervals do not overlap.

    Policy ``i`` gets ``1 +`` the number of policies whose lower bound exceeds
    ``upper[i]``; policies with overlapping intervals can share a rank.
    """
    lo = np.asarray(lower, dtype=np.float64)
    hi = np.asarray(upper, dtype=np.float64)
    if lo.ndim != 1 or lo.shape != hi.shape:
        raise ValueError(f"lower and upper must be 1-D of equal length, got {lo.shape} and {hi.shape}")
    if np.any(lo > hi):
        raise StatsError(f"lower bound above upper bound for policies {np.flatnonzero(lo > hi).tolist()}")
    return 1 + (lo[None, :] > hi[:, None]).sum(axis=1)


# ------------------------------------------------------------------ judge checks

_LETTERS = ("A", "B")


def _letters(values: Iterable, what: str) -> np.ndarray:
    arr = np.array([str(v).strip().upper() for v in values], dtype=object)
    bad = [v for v, a in zip(values, arr) if a not in _LETTERS] if arr.size else []
    if bad:
        raise DataError(f"{what} must be 'A' or 'B', got {bad[:5]!r}" + (" ..." if len(bad) > 5 else ""))
    return arr.astype(str)


def majority_vote(annotator_choices: Mapping) -> dict:
    """Majority letter per pair from ``{pair: [letters of the annotators]}``.

    Pairs whose vote is tied (as many 'A' as 'B') map to ``None``.
    """
    votes = {}
    for pair, choices in annotator_choices.items():
        letters = _letters(list(choices), f"annotator choices for pair {pair!r}")
        n_a = int((letters == "A").sum())
        n_b = letters.size - n_a
        votes[pair] = None if n_a == n_b else ("A" if n_a > n_b else "B")
    return votes


def human_agreement_rate(judge_choices: Mapping, annotator_choices: Mapping) -> float:
    """Share of annotated pairs where the judge picks the annotators' majority letter.

    ``judge_choices``: ``{pair: 'A' | 'B'}`` (a dict or a pandas Series indexed by
    pair); ``annotator_choices``: ``{pair: [letters]}``, e.g.
    ``df.groupby("pair_id")["choice"].agg(list)``.  Only annotated pairs count;
    pairs whose vote is tied are excluded (there is no majority to agree with).
    Every annotated pair needs a judge choice.  Returns NaN when no annotated pair
    has a majority.
    """
    votes = majority_vote(annotator_choices)
    missing = [pair for pair in votes if pair not in judge_choices]
    if missing:
        raise DataError(f"no judge choice for annotated pairs {missing[:5]!r}" + (" ..." if len(missing) > 5 else ""))
    decided = [pair for pair, vote in votes.items() if vote is not None]
    if not decided:
        return float("nan")
    judged = _letters([judge_choices[pair] for pair in decided], "judge choices")
    majority = np.array([votes[pair] for pair in decided])
    return float((judged == majority).mean())


def order_swap_consistency(original: Sequence, swapped: Sequence) -> float:
    """Share of queries that pick the same rollout when the two videos are swapped.

    ``original[k]`` and ``swapped[k]`` are the letters answered for the same pair
    shown in the original and in the swapped order; the answer is consistent when
    'A' in one matches 'B' in the other.
    """
    a = _letters(original, "original answers")
    b = _letters(swapped, "swapped answers")
    if a.size != b.size:
        raise DataError(f"original has {a.size} answers but swapped has {b.size}")
    if a.size == 0:
        raise StatsError("no answers to compare")
    return float((a != b).mean())


class PositionBias(NamedTuple):
    """Share of 'A' answers overall and on pairs whose rollouts had the same outcome.

    An unbiased judge answers 'A' about half the time when the two rollouts are
    equally good; ``same_outcome`` is NaN when no such pair is given.
    """

    overall: float
    same_outcome: float
    n: int
    n_same_outcome: int


def position_bias(letters: Sequence, same_outcome_mask=None) -> PositionBias:
    """Share of 'A' answers overall and on same-outcome pairs (see :class:`PositionBias`).

    ``same_outcome_mask``: booleans, True where both rollouts of the pair succeeded
    or both failed.
    """
    arr = _letters(letters, "answers")
    if arr.size == 0:
        raise StatsError("no answers")
    is_a = arr == "A"
    if same_outcome_mask is None:
        return PositionBias(float(is_a.mean()), float("nan"), int(arr.size), 0)
    mask = np.asarray(same_outcome_mask)
    if mask.shape != arr.shape or mask.dtype != bool:
        raise ValueError(f"same_outcome_mask must be {arr.size} booleans, got {mask.dtype} of shape {mask.shape}")
    n_same = int(mask.sum())
    same = float(is_a[mask].mean()) if n_same else float("nan")
    return PositionBias(float(is_a.mean()), same, int(arr.size), n_same)


# ------------------------------------------------------------- batched ranking metrics


def _paired_batch(scores, reference) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(scores, dtype=np.float64)
    y = np.asarray(reference, dtype=np.float64)
    if x.ndim < 1 or y.ndim < 1 or x.shape[-1] != y.shape[-1]:
        raise StatsError(f"scores and reference need the same number of policies, got shapes {x.shape} and {y.shape}")
    if x.shape[-1] < 2:
        raise StatsError("a ranking metric needs at least 2 policies")
    x, y = np.broadcast_arrays(x, y)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise StatsError("scores and reference must be finite")
    return x, y


def _correlation(x: np.ndarray, y: np.ndarray, constant: np.ndarray) -> np.ndarray:
    xc = x - x.mean(axis=-1, keepdims=True)
    yc = y - y.mean(axis=-1, keepdims=True)
    num = (xc * yc).sum(axis=-1)
    den = np.sqrt((xc * xc).sum(axis=-1) * (yc * yc).sum(axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.clip(num / den, -1.0, 1.0)
    return np.where(constant, np.nan, r)


def _constant(x: np.ndarray) -> np.ndarray:
    return np.all(x == x[..., :1], axis=-1)


def spearman_batch(scores, reference) -> np.ndarray:
    """:func:`spearman` of every row: ``scores`` and ``reference`` broadcast to ``(..., P)``;
    returns ``(...)`` (NaN where either row is constant)."""
    x, y = _paired_batch(scores, reference)
    constant = _constant(x) | _constant(y)
    return _correlation(stats.rankdata(x, axis=-1), stats.rankdata(y, axis=-1), constant)


def pearson_batch(scores, reference) -> np.ndarray:
    """:func:`pearson` of every row, as :func:`spearman_batch`."""
    x, y = _paired_batch(scores, reference)
    return _correlation(x, y, _constant(x) | _constant(y))


def mmrv_batch(scores, reference) -> np.ndarray:
    """:func:`mmrv` of every row, as :func:`spearman_batch` (in the units of ``reference``)."""
    x, y = _paired_batch(scores, reference)
    disagree = (x[..., :, None] > x[..., None, :]) != (y[..., :, None] > y[..., None, :])
    margins = np.where(disagree, np.abs(y[..., :, None] - y[..., None, :]), 0.0)
    return margins.max(axis=-1).mean(axis=-1)


RANKING_METRICS = {"spearman": spearman_batch, "pearson": pearson_batch, "mmrv": mmrv_batch}
