"""Ranking and judge-consistency metrics on hand-checkable cases."""

import math

import numpy as np
import pytest

from r2s_eval.stats import (
    PositionBias,
    ci_aware_rank,
    human_agreement_rate,
    majority_vote,
    mmrv,
    order_swap_consistency,
    pearson,
    position_bias,
    spearman,
)


def test_leader_swap_sanity_case():
    # Real success rates of 6 policies; the judge swaps the two near-tied leaders.
    real = [0.900, 0.879, 0.700, 0.500, 0.300, 0.100]
    judged = [40.0, 41.0, 8.0, 6.0, 3.0, 2.0]
    # Spearman: 1 - 6 * (1 + 1) / (6 * 35) = 0.943.
    assert spearman(judged, real) == pytest.approx(1 - 12 / 210)
    assert round(spearman(judged, real), 3) == 0.943
    # Policies 0 and 1 each violate by the reference margin 0.021: 2 * 0.021 / 6.
    assert mmrv(judged, real) == pytest.approx(2 * 0.021 / 6)
    assert round(mmrv(judged, real), 3) == 0.007


def test_mmrv_is_sized_by_the_reference_argument():
    sim = [3.0, 2.0, 1.0]
    real = [0.5, 0.6, 0.1]
    # Only the pair (0, 1) disagrees.  Sized by real: |0.5 - 0.6| for policies 0 and
    # 1, nothing for 2 -> (0.1 + 0.1 + 0) / 3.  Sized by sim: (1 + 1 + 0) / 3.
    assert mmrv(sim, real) == pytest.approx(0.2 / 3)
    assert mmrv(real, sim) == pytest.approx(2 / 3)
    assert mmrv(sim, real) != pytest.approx(mmrv(real, sim))


def test_mmrv_max_per_policy_and_strict_ties():
    real = [0.9, 0.5, 0.4, 0.1]
    sim = [0.1, 0.5, 0.4, 0.9]  # full reversal
    # Policy 0 violates with all: max margin 0.8; 1: max(0.4, 0.1, 0.4) = 0.4;
    # 2: max(0.5, 0.1, 0.3) = 0.5; 3: 0.8.
    assert mmrv(sim, real) == pytest.approx((0.8 + 0.4 + 0.5 + 0.8) / 4)
    assert mmrv(real, real) == 0.0
    # A tie on the sim side against a strict real order is a violation for the
    # policy that is ahead in real (0.9 > 0.5 but not 1 > 1), sized 0.4.
    assert mmrv([1.0, 1.0], [0.9, 0.5]) == pytest.approx(0.4 / 2)


def test_correlations_with_ties_and_constant_input():
    # Average ranks: [1, 2.5, 2.5, 4] against [1, 2, 3, 4].
    assert spearman([1, 2, 2, 3], [10, 20, 30, 40]) == pytest.approx(np.corrcoef([1, 2.5, 2.5, 4], [1, 2, 3, 4])[0, 1])
    assert spearman([1, 2, 3], [30, 20, 10]) == pytest.approx(-1.0)
    assert pearson([1, 2, 3], [2, 4, 6]) == pytest.approx(1.0)
    assert pearson([1, 2, 3, 4], [1, 3, 2, 4]) == pytest.approx(0.8)
    assert math.isnan(spearman([5, 5, 5], [1, 2, 3]))
    assert math.isnan(pearson([1, 2, 3], [0.5, 0.5, 0.5]))
    with pytest.raises(ValueError, match="3 policies but reference has 2"):
        pearson([1, 2, 3], [1, 2])


def test_ci_aware_rank():
    lower = np.array([50.0, 45.0, 20.0, 5.0])
    upper = np.array([60.0, 55.0, 30.0, 22.0])
    # 0 and 1 overlap (rank 1); 2 is below both leaders; 3 overlaps 2, so only the
    # two leaders are clearly ahead of it.
    np.testing.assert_array_equal(ci_aware_rank(lower, upper), [1, 1, 3, 3])
    with pytest.raises(ValueError, match="lower bound above upper bound for policies \\[1\\]"):
        ci_aware_rank([1.0, 5.0], [2.0, 4.0])


def test_human_agreement_excludes_tied_votes_and_unannotated_pairs():
    judge = {"p1": "A", "p2": "B", "p3": "A", "p4": "B", "p5": "A"}
    annotators = {
        "p1": ["A", "A", "B"],  # majority A, judge agrees
        "p2": ["A", "A", "A"],  # majority A, judge disagrees
        "p3": ["A", "B"],  # tie: excluded
        "p4": ["b", "B", "A"],  # majority B (letters are case-insensitive), agrees
    }  # p5 was not annotated: ignored
    assert majority_vote(annotators) == {"p1": "A", "p2": "A", "p3": None, "p4": "B"}
    assert human_agreement_rate(judge, annotators) == pytest.approx(2 / 3)
    assert math.isnan(human_agreement_rate(judge, {"p3": ["A", "B"]}))
    with pytest.raises(ValueError, match="no judge choice for annotated pairs \\['p9'\\]"):
        human_agreement_rate(judge, {"p9": ["A"]})
    with pytest.raises(ValueError, match="'A' or 'B'"):
        human_agreement_rate({"p1": "C"}, {"p1": ["A"]})


def test_order_swap_consistency():
    original = ["A", "A", "B", "B"]
    swapped = ["B", "A", "A", "B"]  # same video picked in queries 0 and 2
    assert order_swap_consistency(original, swapped) == 0.5
    assert order_swap_consistency(["A"], ["B"]) == 1.0
    with pytest.raises(ValueError, match="2 answers but swapped has 1"):
        order_swap_consistency(["A", "B"], ["A"])


def test_position_bias():
    letters = ["A", "A", "A", "B", "A", "B"]
    same = np.array([True, True, False, True, False, False])
    result = position_bias(letters, same)
    assert isinstance(result, PositionBias)
    assert result.overall == pytest.approx(4 / 6)
    assert result.same_outcome == pytest.approx(2 / 3)
    assert (result.n, result.n_same_outcome) == (6, 3)
    assert math.isnan(position_bias(letters).same_outcome)
    assert math.isnan(position_bias(letters, np.zeros(6, dtype=bool)).same_outcome)
    with pytest.raises(ValueError, match="6 booleans"):
        position_bias(letters, [1, 0, 1, 0, 1, 0])


def test_batched_metrics_match_the_scalar_ones():
    from r2s_eval.stats import mmrv_batch, pearson_batch, spearman_batch

    rng = np.random.default_rng(0)
    scores = rng.integers(0, 5, size=(200, 6)).astype(float)  # ties on both sides
    reference = rng.integers(0, 4, size=(200, 6)) / 4
    scores[3] = 2.0  # a constant row: correlations undefined
    reference[4] = 0.5
    for batch, scalar in ((spearman_batch, spearman), (pearson_batch, pearson), (mmrv_batch, mmrv)):
        got = batch(scores, reference)
        want = np.array([scalar(s, r) for s, r in zip(scores, reference)])
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12, equal_nan=True)
    # A fixed reference broadcasts against a stack of replicates (..., n_boot, P).
    stack = scores.reshape(4, 50, 6)
    np.testing.assert_allclose(spearman_batch(stack, reference[0])[1, 7], spearman(stack[1, 7], reference[0]))
    assert math.isnan(pearson_batch(scores, reference)[3]) and math.isnan(spearman_batch(scores, reference)[4])
    with pytest.raises(ValueError, match="same number of policies"):
        spearman_batch(scores, reference[:, :5])
