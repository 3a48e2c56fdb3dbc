"""Wilson and Newcombe intervals against the closed forms, and the gap bootstrap's bookkeeping."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from r2s_eval.stats.proportions import gap_summary, newcombe_difference, success_gap_cells, wilson_interval

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
