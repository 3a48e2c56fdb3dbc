"""The adaptive allocation's parts: the unit order, the confidence sequence, the pair-picking rule."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from r2s_eval.compare.sequential import PairState, allocate, confidence_sequence, pair_alpha, unit_order
from r2s_eval.errors import ConfigError, DataError


def _episodes(policies=("p0", "p1", "p2"), tasks=("t0", "t1", "t2"), inits=6) -> pd.DataFrame:
    rows = [{"episode_id": f"{p}-{t}-{k}", "policy": p, "task": t, "init_id": k}
            for p in policies for t in tasks for k in range(inits)]
    return pd.DataFrame(rows)


def test_unit_order_compares_each_unit_once_in_balanced_blocks():
    units = unit_order(_episodes(), ["p0", "p1", "p2"], seed=3)
    for (pi, pj), g in units.groupby(["policy_i", "policy_j"]):
        # Every shared (task, init) exactly once: no unit twice, in either orientation.
        assert sorted(zip(g["task"], g["init_id"])) == sorted((t, k) for t in ("t0", "t1", "t2") for k in range(6))
        assert g["pair_index"].tolist() == list(range(len(g)))
        assert g["block"].max() == 2  # 6 inits per task: three blocks of two units per task
        for _, block in g.groupby("block"):
            for _, task in block.groupby("task"):
                assert len(task) == 2 and set(task["policy_a"]) == {pi, pj}  # one unit per side
        assert {e.split("-")[0] for e in g["episode_a"]} | {e.split("-")[0] for e in g["episode_b"]} == {pi, pj}
    # Seeded, and a third policy does not change the first pair's order.
    again = unit_order(_episodes(), ["p0", "p1", "p2"], seed=3)
    pd.testing.assert_frame_equal(units, again)
    two = unit_order(_episodes(policies=("p0", "p1")), ["p0", "p1"], seed=3)
    pd.testing.assert_frame_equal(two, units[(units.policy_i == "p0") & (units.policy_j == "p1")].reset_index(drop=True))
    assert not unit_order(_episodes(), ["p0", "p1", "p2"], seed=4).equals(units)


def test_unit_order_names_a_pair_without_shared_inits():
    eps = _episodes()
    eps = eps[~((eps.policy == "p2") & (eps.task == "t1"))]
    with pytest.raises(DataError, match="'p0' and 'p2' share no initial configuration.*'t1'"):
        unit_order(eps, ["p0", "p1", "p2"], seed=0)
    with pytest.raises(DataError, match="share one init for task 't0'.*two per task"):
        unit_order(_episodes(tasks=("t0",), inits=1), ["p0", "p1"], seed=0)


def test_confidence_sequence_covers_and_shrinks():
    rng = np.random.default_rng(0)
    blocks = rng.binomial(1, 0.75, size=(40, 6)).astype(float)
    widths = [np.subtract(*confidence_sequence(blocks[:n], 0.05)[::-1]) for n in (2, 5, 10, 40)]
    assert all(a > b for a, b in zip(widths, widths[1:]))
    low, high = confidence_sequence(blocks, 0.05)
    assert low < 0.75 < high and low > 0.5
    assert confidence_sequence([], 0.05) == (0.0, 1.0)
    with pytest.raises(DataError, match="scores in"):
        confidence_sequence([[1.2]], 0.05)
    with pytest.raises(ConfigError):
        confidence_sequence([[0.5]], 1.5)


def test_a_clear_pair_is_decided_in_a_block_or_two():
    state = PairState("a", "b", blocks_left=10, alpha=pair_alpha(0.05, 15))
    state.add([1.0] * 14)
    state.add([1.0] * 13 + [0.0])
    assert state.decided and state.winner == "a" and state.comparisons == 28


def _null_block(rng, tasks=3, bias=0.3):
    """One block of a judge that cannot tell the policies apart but says A far more often: per
    task one comparison with policy_i as A, one as B."""
    a_first = rng.random(tasks) < 0.5 + bias
    a_second = rng.random(tasks) < 0.5 + bias
    return np.r_[a_first, ~a_second].astype(float)  # policy_i is A in the first, B in the second


def test_stopping_rule_almost_never_declares_an_order_between_equal_policies():
    """The null world, with a judge biased towards A: looking after every block, for up to 60
    blocks, the rule may declare an order in at most alpha of the runs."""
    rng = np.random.default_rng(1)
    declared = 0
    for _ in range(300):
        state = PairState("a", "b", blocks_left=60, alpha=0.05)
        for _ in range(60):
            state.add(_null_block(rng))
            if state.decided:
                declared += 1
                break
    assert declared / 300 <= 0.05


def test_allocate_settles_clear_pairs_first_and_skips_closed_ones():
    decided = PairState("a", "b", blocks_left=5, alpha=0.05)
    decided.add([1.0] * 14)
    decided.add([1.0] * 14)
    assert decided.decided and decided.winner == "a"
    fresh = PairState("a", "c", blocks_left=5, alpha=0.05)
    clear = PairState("b", "c", blocks_left=5, alpha=0.05)
    clear.add([1.0] * 5 + [0.0])
    close = PairState("b", "d", blocks_left=5, alpha=0.05)
    close.add([1.0] * 3 + [0.0] * 3)
    exhausted = PairState("c", "d", blocks_left=0, alpha=0.05)
    picks = allocate([decided, fresh, clear, close, exhausted], 3, [6] * 5)
    assert picks[:2] == [1, 2]  # no evidence yet, then the pair nearest to a decision
    assert 0 not in picks and 4 not in picks
    assert allocate([decided, exhausted], 4) == []
    assert allocate([PairState("a", "b", blocks_left=2, alpha=0.05)], 5) == [0, 0]  # no more than its blocks


def test_pair_alpha_splits_the_ranking_error():
    assert pair_alpha(0.05, 5) == pytest.approx(0.01)
    with pytest.raises(ConfigError, match="compare.alpha"):
        pair_alpha(0.0, 3)
