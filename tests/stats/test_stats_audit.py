"""Judge report card statistics: unit-bootstrap shares and the shuffled-label control."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from r2s_eval.stats import flat_within_ci, shuffled_label_control, unit_share


def test_unit_share_counts_and_interval():
    hits = [True, True, False, True, True, True]
    units = [("t", 0), ("t", 0), ("t", 1), ("t", 1), ("t", 2), ("t", 3)]
    out = unit_share(hits, units, n_boot=500, level=0.95, seed=1)
    assert out["share"] == pytest.approx(5 / 6)
    assert out["n_pairs"] == 6 and out["n_units"] == 4
    assert 0.0 <= out["ci_low"] <= out["share"] <= out["ci_high"] <= 1.0
    assert out["ci_low"] < out["ci_high"]
    assert unit_share(hits, units, n_boot=500, level=0.95, seed=1) == out  # deterministic


def test_unit_share_all_hits_gives_a_degenerate_interval_and_empty_gives_none():
    out = unit_share([True] * 4, [0, 1, 2, 3], n_boot=200, level=0.95)
    assert (out["share"], out["ci_low"], out["ci_high"]) == (1.0, 1.0, 1.0)
    empty = unit_share([], [], n_boot=200, level=0.95)
    assert empty["share"] is None and empty["n_pairs"] == 0 and empty["n_units"] == 0


def test_unit_share_resamples_units_not_verdicts():
    # One unit with 10 hits and one with 10 misses: unit resampling draws 0, 1/2 or 1.
    out = unit_share([True] * 10 + [False] * 10, ["u"] * 10 + ["v"] * 10, n_boot=2000, level=0.95, seed=0)
    assert out["share"] == 0.5 and out["n_units"] == 2
    assert out["ci_low"] == 0.0 and out["ci_high"] == 1.0


def test_flat_within_ci():
    assert flat_within_ci([20, 25, 30], [40, 40, 40])["flat"]  # all contain 33.3
    no = flat_within_ci([60, 10, 5], [80, 30, 20])
    assert not no["flat"] and not no["contains_uniform"] and not no["all_overlap"]
    overlap_only = flat_within_ci([35, 30, 20], [45, 40, 36])  # 35-36 overlap, 33.3 not in the first
    assert overlap_only["all_overlap"] and not overlap_only["flat"]


def _strict_judge(n_tasks=2, n_inits=8, prefer="p0"):
    """Every policy pair compared once per (task, init); the judge always prefers ``prefer``
    and otherwise answers by a fixed per-unit coin, so the other policies tie on average."""
    rng = np.random.default_rng(3)
    policies = ["p0", "p1", "p2"]
    rows = []
    for t, u in itertools.product(range(n_tasks), range(n_inits)):
        for a, b in itertools.combinations(policies, 2):
            a_won = True if a == prefer else (False if b == prefer else bool(rng.random() < 0.5))
            rows.append((a, b, a_won, f"t{t}", u))
    pi, pj, won, task, init = map(list, zip(*rows))
    return policies, pi, pj, won, task, init


@pytest.mark.filterwarnings("ignore:.*did not converge:RuntimeWarning")  # the real fit sits at the boundary
def test_shuffled_label_control_real_fit_is_not_flat_but_permuted_fits_are():
    policies, pi, pj, won, task, init = _strict_judge()
    out = shuffled_label_control(pi, pj, won, task, init, policies=policies, n_permutations=20, n_boot=200, level=0.95, seed=0)
    real = out["real"]
    assert not real["flat"] and not real["all_overlap"]
    assert real["ci_low"]["p0"] > 100 / 3  # the preferred policy clearly above uniform
    assert real["scores"]["p0"] > 99  # a strict preference: p0 takes (almost) all the strength
    assert out["n_permutations"] == 20 and len(out["permuted"]) == 20
    # Permuted labels carry no information: most fits are flat (the unit bootstrap resamples each
    # policy pair's units separately, so it is somewhat narrow here and not every fit is flat).
    assert out["permuted_flat_share"] >= 0.5 and out["permuted_overlap_share"] >= 0.5
    spreads = [max(f["scores"].values()) - min(f["scores"].values()) for f in out["permuted"]]
    assert np.median(spreads) < 40
    for fit in out["permuted"]:
        assert sum(fit["scores"].values()) == pytest.approx(100.0)


@pytest.mark.filterwarnings("ignore:.*did not converge:RuntimeWarning")
def test_shuffled_label_control_is_seeded():
    policies, pi, pj, won, task, init = _strict_judge(n_inits=4)
    kw = dict(policies=policies, n_permutations=3, n_boot=100, level=0.95)
    assert shuffled_label_control(pi, pj, won, task, init, seed=5, **kw) == \
        shuffled_label_control(pi, pj, won, task, init, seed=5, **kw)
