"""Agreement among human annotators on A/B pairs: vote counts, majority, unanimity, Fleiss' kappa.

Every function takes a vote table: one row per annotated pair, columns ``A`` and ``B`` holding
how many annotators chose each video (in one fixed orientation per pair). Fleiss' kappa is
statsmodels' implementation; it needs the same number of raters on every pair, so it is computed
on the pairs that have the most common number of votes (at least two), and that count is
reported with it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.errors import DataError

# Outcome categories of a pair of rollouts (sim outcomes), the strata of the human agreement.
SUCCESS_SUCCESS, FAILURE_FAILURE, MIXED = "success-success", "failure-failure", "success-failure"
OUTCOME_CATEGORIES: tuple[str, ...] = (SUCCESS_SUCCESS, FAILURE_FAILURE, MIXED)


def outcome_category(success_a: bool, success_b: bool) -> str:
    """The outcome category of a pair of rollouts (the order does not matter)."""
    if success_a and success_b:
        return SUCCESS_SUCCESS
    if not success_a and not success_b:
        return FAILURE_FAILURE
    return MIXED


def vote_table(pairs, letters) -> pd.DataFrame:
    """Count the letters ('A'/'B') per pair label; rows in first-seen order of the pairs."""
    frame = pd.DataFrame({"pair": list(pairs), "letter": [str(x).strip().upper() for x in letters]})
    bad = sorted(set(frame["letter"]) - {"A", "B"})
    if bad:
        raise DataError(f"votes must be A or B, got {bad[:5]}")
    counts = frame.groupby(["pair", "letter"], sort=False).size().unstack(fill_value=0)
    counts = counts.reindex(columns=["A", "B"], fill_value=0)
    return counts.reindex(pd.unique(frame["pair"])).astype(int)


def majority_letters(votes: pd.DataFrame) -> pd.Series:
    """'A' or 'B' where more annotators chose it; None where the vote is tied."""
    a, b = votes["A"].to_numpy(), votes["B"].to_numpy()
    return pd.Series(np.where(a > b, "A", np.where(b > a, "B", None)), index=votes.index, dtype=object)


def unanimous(votes: pd.DataFrame) -> pd.Series:
    """Whether all annotators of a pair chose the same video, for pairs with at least two votes."""
    n = votes["A"] + votes["B"]
    several = votes[n >= 2]
    return (several["A"] == 0) | (several["B"] == 0)


def fleiss(votes: pd.DataFrame) -> dict:
    """Fleiss' kappa over the pairs rated by the most common number (>= 2) of annotators.

    Returns ``kappa`` (None when undefined: no such pairs, or every vote for one letter),
    ``n_pairs`` it rests on and ``n_raters`` per pair; the letters are the two categories.
    """
    n = (votes["A"] + votes["B"]).to_numpy()
    counts = pd.Series(n[n >= 2]).value_counts()
    if counts.empty:
        return {"kappa": None, "n_pairs": 0, "n_raters": 0}
    raters = int(max(counts.index, key=lambda k: (counts[k], k)))  # most pairs; ties: more raters
    table = votes[["A", "B"]].to_numpy()[n == raters]
    with np.errstate(invalid="ignore", divide="ignore"):
        from statsmodels.stats.inter_rater import fleiss_kappa  # a second's import: only where kappa is computed

        kappa = float(fleiss_kappa(table, method="fleiss"))
    return {"kappa": None if not np.isfinite(kappa) else kappa, "n_pairs": int(len(table)), "n_raters": raters}
