"""Wilson and Newcombe intervals against the closed forms, and the gap bootstrap's bookkeeping."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from r2s_eval.errors import DataError
from r2s_eval.stats.proportions import (gap_summary, newcombe_difference, paired_outcomes, success_counts,
                                        success_gap_cells, wilson_interval)

Z95 = 1.959963984540054


def wilson_by_hand(s: int, n: int, z: float = Z95) -> tuple[float, float]:
    p = s / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return centre - half, centre + half


@pytest.mark.parametrize("s,n", [(0, 6), (1, 6), (3, 6), (6, 6), (7, 20)])
def test_wilson_matches_its_closed_form(s, n):
    assert wilson_interval(s, n, level=0.95) == pytest.approx(wilson_by_hand(s, n), abs=1e-9)


def test_newcombe_is_built_from_the_two_wilson_intervals():
    (l1, u1), (l2, u2) = wilson_by_hand(3, 6), wilson_by_hand(1, 6)
    d = 3 / 6 - 1 / 6
    expected = (d - math.sqrt((3 / 6 - l1) ** 2 + (u2 - 1 / 6) ** 2), d + math.sqrt((u1 - 3 / 6) ** 2 + (1 / 6 - l2) ** 2))
    assert newcombe_difference(3, 6, 1, 6, level=0.95) == pytest.approx(expected, abs=1e-9)
    assert wilson_interval(0, 0, level=0.95) is None and newcombe_difference(1, 2, 0, 0, level=0.95) is None


def test_cells_need_both_sides_and_the_bootstrap_is_seeded():
    reference = pd.DataFrame({"policy": ["p", "p", "q"], "task": ["a", "b", "a"], "trials": [4, 4, 4],
                              "successes": [2, 4, 0]})
    sim = pd.DataFrame({"policy": ["p"] * 4 + ["q"] * 4 + ["r"] * 2, "task": ["a"] * 10,
                        "success": [True, True, True, False, False, False, False, False, True, True]})
    cells = success_gap_cells(reference, sim, level=0.95)
    assert sorted(zip(cells["policy"], cells["task"])) == [("p", "a"), ("q", "a")]  # p/b has no sim, r no real
    assert cells.set_index("policy").loc["p", "gap"] == pytest.approx(0.25)
    a, b = gap_summary(cells, level=0.95, n_boot=300, seed=1), gap_summary(cells, level=0.95, n_boot=300, seed=1)
    assert a == b and a["cells"] == 2 and a["mean_abs_gap_pp"] == pytest.approx(12.5)
    lo, hi = a["mean_abs_gap_ci_pp"]
    assert lo <= a["mean_abs_gap_pp"] <= hi and a["max_abs_gap_pp"] == pytest.approx(25.0)
    assert gap_summary(cells.iloc[:0], level=0.95, n_boot=300) == {"cells": 0}


def episodes(rows):
    """(policy, task, init_id, success) rows as an episode table."""
    return pd.DataFrame(rows, columns=["policy", "task", "init_id", "success"])


def correlated_sides(n: int = 60, flips: int = 6):
    """Two worlds on the same n inits of one task: the sim repeats the real outcome except on
    ``flips`` inits (real failures it turns into successes)."""
    real = [i % 2 == 0 for i in range(n)]
    sim = [r or (i % 2 == 1 and i < 2 * flips) for i, r in enumerate(real)]
    return (episodes([("p", "a", i, s) for i, s in enumerate(real)]),
            episodes([("p", "a", i, s) for i, s in enumerate(sim)]))


def test_paired_outcomes_join_each_init_of_a_cell_and_refuse_what_cannot_be_paired():
    real, sim = correlated_sides(n=4, flips=1)
    paired = paired_outcomes(real, sim)
    assert paired.to_dict("list") == {"policy": ["p"] * 4, "task": ["a"] * 4, "init_id": [0, 1, 2, 3],
                                      "real": [True, False, True, False], "sim": [True, True, True, False]}
    other_cell = episodes([("q", "a", 0, True)])  # a cell only one side has is left out, not refused
    assert paired_outcomes(pd.concat([real, other_cell]), sim).equals(paired)
    assert paired_outcomes(real, sim.assign(init_id=[0, 1, 2, 7])) is None  # different inits
    assert paired_outcomes(real, pd.concat([sim, sim.iloc[:1]])) is None  # an init run twice
    assert paired_outcomes(real.drop(columns="init_id"), sim) is None  # no init ids


def test_the_paired_interval_keeps_the_correlation_of_two_worlds_on_the_same_inits():
    real, sim = correlated_sides(n=60, flips=6)
    reference = success_counts(real)
    cells = success_gap_cells(reference, sim, level=0.95)
    independent = gap_summary(cells, level=0.95, n_boot=2000, seed=3)
    paired = gap_summary(cells, level=0.95, n_boot=2000, seed=3, paired=paired_outcomes(real, sim))
    assert paired["paired"] and not independent["paired"] and "shared initial" in paired["interval"]
    assert paired["mean_gap_pp"] == independent["mean_gap_pp"] == pytest.approx(10.0)
    lo, hi = paired["mean_gap_ci_pp"]
    # the sim never does worse than the real side on an init: no redraw can make the gap negative,
    # while independent binomial draws of two rates near 50 % span about +-18 pp around it
    assert 0.0 <= lo < 10.0 < hi
    assert hi - lo < 0.6 * (independent["mean_gap_ci_pp"][1] - independent["mean_gap_ci_pp"][0])
    same = gap_summary(success_gap_cells(reference, real, 0.95), 0.95, 500, 3, paired=paired_outcomes(real, real))
    assert same["mean_gap_ci_pp"] == [0.0, 0.0]  # the same outcomes on every init: no gap in any redraw


def test_uncorrelated_worlds_get_about_the_independent_interval():
    rng = np.random.default_rng(0)
    n = 200
    real = episodes([("p", "a", i, s) for i, s in enumerate(rng.random(n) < 0.5)])
    sim = episodes([("p", "a", i, s) for i, s in enumerate(rng.random(n) < 0.5)])
    cells = success_gap_cells(success_counts(real), sim, level=0.95)
    widths = [np.diff(gap_summary(cells, 0.95, 4000, 1, paired=p)["mean_gap_ci_pp"])[0]
              for p in (None, paired_outcomes(real, sim))]
    assert widths[1] == pytest.approx(widths[0], rel=0.15)


def test_a_task_s_cells_share_each_redraw_of_its_inits():
    # two policies with the same outcomes on the same inits: every redraw moves both cells alike,
    # so the mean over them spreads as one cell does (independent cells would halve the variance)
    real, sim = correlated_sides(n=40, flips=4)
    both = [pd.concat([side, side.assign(policy="q")], ignore_index=True) for side in (real, sim)]
    one = gap_summary(success_gap_cells(success_counts(real), sim, 0.95), 0.95, 1000, 2,
                      paired=paired_outcomes(real, sim))
    two = gap_summary(success_gap_cells(success_counts(both[0]), both[1], 0.95), 0.95, 1000, 2,
                      paired=paired_outcomes(*both))
    assert two["cells"] == 2 and two["mean_gap_ci_pp"] == one["mean_gap_ci_pp"]


def test_paired_trials_that_are_not_the_table_s_are_refused_naming_the_cell():
    real, sim = correlated_sides(n=10, flips=1)
    cells = success_gap_cells(success_counts(real), sim, level=0.95)
    wrong = paired_outcomes(real.assign(success=True), sim)
    with pytest.raises(DataError, match="policy p, task a: the episodes"):
        gap_summary(cells, 0.95, 100, 0, paired=wrong)
