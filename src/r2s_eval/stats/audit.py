"""Judge report card statistics: agreement shares with unit-bootstrap intervals and the
shuffled-label control of the Bradley-Terry fit.

* :func:`unit_share` -- a share of hits (e.g. verdicts preferring the successful rollout)
  with a percentile interval from a bootstrap over the distinct units (the (task, init)
  rollout settings): a replicate draws as many units as there are, with replacement, and
  pools their hits and trials.
* :func:`shuffled_label_control` -- the policy labels permuted at random within each unit
  (one permutation of the policies per (task, init), applied to every comparison there, so
  each unit keeps its design and only the policy names move), refitted with the unit
  bootstrap; a judge whose verdicts carry real information about the policies gives a
  non-flat real fit and flat permuted fits.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from r2s_eval.errors import StatsError
from r2s_eval.stats.bradley_terry import bt_confidence_intervals, bt_scores, fit_bradley_terry
from r2s_eval.stats.units import comparison_units, tagged_seed, unit_bootstrap_bradley_terry

SHARE_KEY = 0x73686172  # spawn-key tag of the share bootstrap ("shar")
SHUFFLE_KEY = 0x73687566  # spawn-key tag of the label permutations ("shuf")


def unit_share(hits, units: Sequence, *, n_boot: int, level: float, seed=0) -> dict:
    """Share of ``hits`` (booleans, one per verdict) with its unit-bootstrap percentile interval.

    ``units``: one hashable label per verdict (e.g. ``(task, init_id)``). Returns ``share``,
    ``ci_low``, ``ci_high`` (None when there is no verdict), ``n_pairs``, ``n_units``,
    ``ci_level`` and ``interval`` ("unit bootstrap").
    """
    hit = np.asarray(hits, dtype=bool)
    if hit.ndim != 1 or len(units) != hit.size:
        raise StatsError("hits and units must be 1-D of equal length")
    out = {"share": None, "ci_low": None, "ci_high": None, "n_pairs": int(hit.size), "n_units": 0,
           "ci_level": float(level), "interval": "unit bootstrap over (task, init)"}
    if hit.size == 0:
        return out
    label = pd.factorize(pd.Series(list(units)))[0]
    U = int(label.max()) + 1
    k = np.bincount(label, weights=hit, minlength=U)
    n = np.bincount(label, minlength=U).astype(float)
    draws = np.random.default_rng(tagged_seed(seed, SHARE_KEY)).integers(0, U, size=(int(n_boot), U))
    boot = k[draws].sum(axis=1) / n[draws].sum(axis=1)
    alpha = (1 - level) / 2
    low, high = np.quantile(boot, [alpha, 1 - alpha])
    out.update(share=float(hit.mean()), ci_low=float(low), ci_high=float(high), n_units=U)
    return out


def flat_within_ci(ci_low, ci_high) -> dict:
    """Whether a ranking is flat within its intervals (scores on the 0-100 scale).

    ``contains_uniform``: every interval holds 100 / n_policies; ``all_overlap``: every pair
    of intervals overlaps (in one dimension: the largest lower end is at most the smallest
    upper end). ``flat`` is ``contains_uniform``, the stricter of the two.
    """
    lo, hi = np.asarray(ci_low, dtype=float), np.asarray(ci_high, dtype=float)
    uniform = 100.0 / lo.size
    contains = bool(np.all((lo <= uniform) & (uniform <= hi)))
    overlap = bool(lo.max() <= hi.min())
    return {"flat": contains, "contains_uniform": contains, "all_overlap": overlap}


def _fit_with_ci(i, j, i_won, task, init, P, n_boot, level, seed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    units = comparison_units(i, j, i_won, list(init), n_policies=P, stratum=list(task))
    scores = bt_scores(fit_bradley_terry(units.wins()[0]))
    boot = unit_bootstrap_bradley_terry(units, n_boot=n_boot, seed=seed)
    low, high = bt_confidence_intervals(boot, level=level)
    return scores, low[0], high[0]


def shuffled_label_control(policy_i, policy_j, i_won, task, init, *, policies: Sequence[str],
                           n_permutations: int, n_boot: int, level: float, seed=0) -> dict:
    """The BT fit with unit-bootstrap CIs on the real labels and on ``n_permutations`` label
    permutations (all comparisons given: the last checkpoint).

    ``policy_i``, ``policy_j``: policy names per comparison; ``i_won``: whether ``policy_i``
    was preferred; ``task``, ``init``: each comparison's unit. Permutation ``r`` draws, for
    every (task, init), one random permutation of the policies (``default_rng`` seeded with
    ``seed`` tagged by :data:`SHUFFLE_KEY` and ``r``) and renames both policies of each
    comparison there by it; the outcome of each comparison stays with its rollout, so the
    design is unchanged and only which policy is which is lost.
    """
    names = list(policies)
    P = len(names)
    index = {p: k for k, p in enumerate(names)}
    i = np.array([index[str(p)] for p in policy_i], dtype=np.int64)
    j = np.array([index[str(p)] for p in policy_j], dtype=np.int64)
    won = np.asarray(i_won, dtype=bool)
    task, init = [str(t) for t in task], list(init)
    unit = pd.factorize(pd.Series(list(zip(task, init))))[0]
    U = int(unit.max()) + 1 if unit.size else 0

    def summary(scores, low, high) -> dict:
        return {"scores": {n: float(s) for n, s in zip(names, scores)},
                "ci_low": {n: float(v) for n, v in zip(names, low)},
                "ci_high": {n: float(v) for n, v in zip(names, high)}, **flat_within_ci(low, high)}

    real = summary(*_fit_with_ci(i, j, won, task, init, P, n_boot, level, seed))
    permuted = []
    for r in range(int(n_permutations)):
        rng = np.random.default_rng(tagged_seed(seed, SHUFFLE_KEY, r))
        perm = np.argsort(rng.random((U, P)), axis=1)  # one permutation of the policies per unit
        pi, pj = perm[unit, i], perm[unit, j]
        permuted.append(summary(*_fit_with_ci(pi, pj, won, task, init, P, n_boot, level, seed)))
    flat = [p["flat"] for p in permuted]
    return {
        "policies": names, "n_permutations": len(permuted), "n_boot": int(n_boot), "ci_level": float(level),
        "interval": "unit", "flat_rule": "every score's CI contains 100 / n_policies",
        "real": real, "permuted_flat_share": float(np.mean(flat)) if flat else None,
        "permuted_overlap_share": float(np.mean([p["all_overlap"] for p in permuted])) if permuted else None,
        "permuted": permuted,
    }
