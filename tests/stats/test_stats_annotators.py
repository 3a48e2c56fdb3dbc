"""Agreement among annotators: vote tables, majority, unanimity and Fleiss' kappa by hand."""

from __future__ import annotations

import pytest

from r2s_eval.stats import fleiss, majority_letters, outcome_category, unanimous, vote_table


def test_vote_table_majority_and_unanimity():
    votes = vote_table(["p1", "p1", "p1", "p2", "p2", "p2", "p3", "p3", "p4"],
                       ["A", "a", "B", "B", "B", "B", "A", "B", "A"])
    assert votes.to_dict("index") == {"p1": {"A": 2, "B": 1}, "p2": {"A": 0, "B": 3}, "p3": {"A": 1, "B": 1},
                                      "p4": {"A": 1, "B": 0}}
    assert majority_letters(votes).tolist() == ["A", "B", None, "A"]
    # p4 has one vote: unanimity needs at least two.
    assert unanimous(votes).to_dict() == {"p1": False, "p2": True, "p3": False}
    with pytest.raises(ValueError, match="votes must be A or B"):
        vote_table(["p1"], ["C"])


def test_fleiss_kappa_by_hand():
    # Four pairs, three raters: A A A, B B B, A A B, A B B.
    votes = vote_table([p for p in "1112223334445" for _ in [0]], list("AAABBBAABABBA"))
    # P_i: 1, 1, 1/3, 1/3 -> P_bar = 2/3; p_A = p_B = 1/2 -> P_e = 1/2; kappa = (2/3 - 1/2) / (1/2) = 1/3.
    # Pair 5 has one vote and is left out: kappa rests on the four pairs with three raters.
    out = fleiss(votes)
    assert out == {"kappa": pytest.approx(1 / 3), "n_pairs": 4, "n_raters": 3}


def test_fleiss_kappa_undefined_or_without_pairs():
    assert fleiss(vote_table(["1", "1", "2", "2"], ["A", "A", "A", "A"]))["kappa"] is None  # no variation at all
    assert fleiss(vote_table(["1", "2"], ["A", "B"])) == {"kappa": None, "n_pairs": 0, "n_raters": 0}


def test_outcome_categories():
    assert [outcome_category(a, b) for a, b in [(True, True), (False, False), (True, False), (False, True)]] == [
        "success-success", "failure-failure", "success-failure", "success-failure"]
