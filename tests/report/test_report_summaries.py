"""Numbers behind the reports, checked by hand on small constructed artefacts."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from r2s_eval.report import (
    judge_audit,
    judge_averaged_scores,
    pick_case_study,
    success_by_task,
    success_gaps,
    task_summary,
    win_rate_matrix,
)


def test_task_summary_counts_real_sim_and_replay_success():
    index = pd.DataFrame({"episode_index": [0, 1, 2, 3, 4], "task": ["t1", "t1", "t1", "t2", "t2"]})
    log = pd.DataFrame({"episode_index": [0, 1, 2, 3, 4, 9], "task": ["t1", "t1", "t1", "t2", "t2", "t2"],
                        "success": [True, False, True, True, True, False]})  # episode 9 was not ingested
    table = task_summary(index, log)
    assert table["task"].tolist() == ["t1", "t2"]
    assert table["real"].tolist() == [3, 2] and table["sim"].tolist() == [2, 2]
    assert table["replay_success"].tolist() == pytest.approx([2 / 3, 1.0])


def test_task_summary_names_unreplayed_episodes():
    index = pd.DataFrame({"episode_index": [0, 7], "task": ["t1", "t1"]})
    log = pd.DataFrame({"episode_index": [0], "task": ["t1"], "success": [True]})
    with pytest.raises(ValueError, match=r"\[7\]"):
        task_summary(index, log)

# The values conf/ gives every stage (conf/stats/default.yaml ci_level, config.yaml seed).
STATS = {"ci_level": 0.95, "seed": 0}


@pytest.fixture
def success():
    reference = pd.DataFrame({"policy": ["a", "a", "b"], "task": ["t1", "t2", "t1"],
                              "trials": [10, 10, 10], "successes": [8, 5, 2]})
    sim = pd.DataFrame({
        "policy": ["a"] * 6 + ["b"] * 4,
        "task": ["t1"] * 4 + ["t2"] * 2 + ["t1", "t1", "t2", "t2"],
        "success": [True, True, True, False, True, False, False, False, True, True],
    })
    return success_by_task(reference, sim)


def test_success_by_task_cells_and_totals(success):
    cells = success.set_index(["policy", "task"])
    assert cells.loc[("a", "t1"), ["real", "sim"]].tolist() == pytest.approx([0.8, 0.75])
    assert cells.loc[("a", "t2"), ["real", "sim"]].tolist() == pytest.approx([0.5, 0.5])
    assert cells.loc[("b", "t1"), ["real", "sim"]].tolist() == pytest.approx([0.2, 0.0])
    assert math.isnan(cells.loc[("b", "t2"), "real"]) and cells.loc[("b", "t2"), "sim"] == 1.0
    # Totals are the mean of the per-task rates (every task weighs the same), not pooled trials:
    # a's sim side is (3/4 + 1/2) / 2 = 0.625, where pooling would give 4/6.
    assert cells.loc[("a", "total"), ["real", "sim"]].tolist() == pytest.approx([(0.8 + 0.5) / 2, 0.625])
    assert cells.loc[("b", "total"), ["real", "sim"]].tolist() == pytest.approx([0.2, 0.5])
    assert cells.loc[("a", "total"), ["real_trials", "sim_trials"]].tolist() == [20, 6]
    assert cells.loc[("a", "t1"), ["real_trials", "sim_trials"]].tolist() == [10, 4]


def test_success_gaps_in_percentage_points(success):
    gaps = success_gaps(success)
    assert gaps.loc["t1"].tolist() == pytest.approx([12.5, 20.0])  # |80-75| and |20-0|
    assert gaps.loc["t2"].tolist() == pytest.approx([0.0, 0.0])  # b has no real t2 trials
    assert gaps.loc["total"].tolist() == pytest.approx([(2.5 + 30) / 2, 30.0])  # |65-62.5|, |20-50|


def test_audit_position_bias_without_swaps_or_annotations(verdicts, sim_episodes):
    audit = judge_audit(verdicts, sim_episodes, swapped_letter_columns=["swapped_verdict"], n_boot=100, **STATS, shuffled_permutations=20)
    assert audit["a_share"] == pytest.approx(4 / 6)
    # Same outcome: a1/b1 (both succeed, answered A) and c2/b2 (both fail, answered B).
    assert audit["n_same_outcome"] == 2 and audit["a_share_same_outcome"] == pytest.approx(0.5)
    assert audit["swap_consistency"] is None and audit["n_swapped"] == 0
    assert audit["human_agreement"] is None


def test_audit_swap_consistency_from_letters(verdicts, sim_episodes):
    verdicts["swapped_letter"] = ["A", None, "B", "B", "B", None]  # original letters A, B, A, A, A, B
    audit = judge_audit(verdicts, sim_episodes, swapped_letter_columns=["swapped_verdict", "swapped_letter"], n_boot=100, **STATS, shuffled_permutations=20)
    assert audit["n_swapped"] == 4 and audit["swap_column"] == "swapped_letter"
    assert audit["swap_consistency"] == pytest.approx(3 / 4)  # only the first audited row kept its letter


def test_audit_swap_consistency_skips_empty_answers(verdicts, sim_episodes):
    # The judge stage writes "" where a pair was not audited or its swapped answer was invalid.
    verdicts["verdict_swapped"] = ["B", "", "", "B", "", "A"]  # original letters A, B, A, A, A, B
    audit = judge_audit(verdicts, sim_episodes, swapped_letter_columns=["verdict_swapped"], n_boot=100, **STATS, shuffled_permutations=20)
    assert audit["n_swapped"] == 3 and audit["swap_consistency"] == pytest.approx(1.0)
    verdicts["verdict_swapped"] = ""
    assert judge_audit(verdicts, sim_episodes, swapped_letter_columns=["verdict_swapped"], n_boot=100, **STATS, shuffled_permutations=20)["swap_consistency"] is None


def test_audit_swap_consistency_from_winners(verdicts, sim_episodes):
    verdicts["swapped_winner"] = ["a", None, "a", "a", "c", None]  # winners a, a, c, a, b, b
    audit = judge_audit(verdicts, sim_episodes, swapped_winner_columns=["swapped_winner"], n_boot=100, **STATS, shuffled_permutations=20)
    assert audit["n_swapped"] == 4 and audit["swap_consistency"] == pytest.approx(0.5)


def test_audit_human_agreement_majority_and_flipped_order(verdicts, sim_episodes):
    annotations = pd.DataFrame({
        "episode_a": ["a1", "a1", "a1", "a2", "c1", "b1", "b1"],
        "episode_b": ["b1", "b1", "b1", "b2", "a1", "c1", "c1"],
        "choice": ["A", "a", "B", "A", "B", "A", "B"],
        "annotator": ["x", "y", "z", "x", "x", "x", "y"],
    })
    audit = judge_audit(verdicts, sim_episodes, annotations=annotations, n_boot=100, **STATS, shuffled_permutations=20)
    # a1/b1: majority A, judge A (agree). a2/b2 was shown to the judge as b2/a2 and answered B (a2):
    # the annotator's A for a2 agrees. c1/a1: annotator B, judge A. b1/c1: tied vote, left out.
    assert audit["human_agreement"] == pytest.approx(2 / 3)
    assert audit["n_annotated_pairs"] == 4 and audit["n_annotations"] == 7


def test_audit_human_agreement_by_outcome_category(verdicts, sim_episodes):
    annotations = pd.DataFrame({
        # a1/b1 both succeeded: 2-1 for a1 (the judge's pick). b2/c2 both failed, shown the other way
        # round than the judge saw it: 3-0 for b2 (the judge's pick). a1/c1 mixed: 2-1 for a1, the
        # judge picked c1.
        "episode_a": ["a1", "a1", "a1", "b2", "b2", "b2", "a1", "a1", "a1"],
        "episode_b": ["b1", "b1", "b1", "c2", "c2", "c2", "c1", "c1", "c1"],
        "choice": ["A", "A", "B", "A", "A", "A", "A", "A", "B"],
        "annotator": ["x", "y", "z"] * 3,
    })
    audit = judge_audit(verdicts, sim_episodes, annotations=annotations, n_boot=200, **STATS, shuffled_permutations=20)
    human = audit["human"]
    assert audit["human_agreement"] == pytest.approx(2 / 3) and human["n_annotators"] == 3
    assert human["votes_per_pair"] == {"3": 3} and human["n_tied_pairs"] == 0 and human["n_unjudged_pairs"] == 0
    assert [(p["episode_a"], p["episode_b"], p["votes_a"], p["votes_b"], p["majority"]) for p in human["pairs"]] == [
        ("a1", "b1", 2, 1, "a1"), ("b2", "c2", 3, 0, "b2"), ("a1", "c1", 2, 1, "a1")]
    assert human["unanimous"]["share"] == pytest.approx(1 / 3) and human["unanimous"]["n_pairs"] == 3
    # Votes per pair (A, B): (2, 1), (3, 0), (2, 1): P_bar = 5/9, P_e = (7/9)^2 + (2/9)^2 = 53/81.
    assert human["fleiss"]["kappa"] == pytest.approx((5 / 9 - 53 / 81) / (1 - 53 / 81))
    by = human["by_category"]
    assert set(by) == {"success-success", "failure-failure", "success-failure"}
    assert by["success-success"]["judge_agreement"]["share"] == 1.0
    assert by["failure-failure"]["judge_agreement"]["share"] == 1.0 and by["failure-failure"]["unanimous"]["share"] == 1.0
    assert by["success-failure"]["judge_agreement"]["share"] == 0.0
    ci = human["judge_agreement"]
    # The three verdicts sit at two (task, init) units: a1/b1 and a1/c1 were both compared at init 0.
    assert ci["ci_low"] <= ci["share"] <= ci["ci_high"] and ci["n_pairs"] == 3 and ci["n_units"] == 2


def test_audit_counts_annotated_pairs_the_judge_never_compared(verdicts, sim_episodes):
    # A judge may lack an annotated pair (an excluded comparison): it is counted, not scored.
    annotations = pd.DataFrame({"episode_a": ["a1", "a1"], "episode_b": ["c2", "b1"], "choice": ["A", "A"]})
    audit = judge_audit(verdicts, sim_episodes, annotations=annotations, annotations_source="ann.csv", n_boot=100, **STATS, shuffled_permutations=20)
    assert audit["human"]["n_unjudged_pairs"] == 1 and audit["n_annotated_pairs"] == 2
    assert audit["human_agreement"] == 1.0 and audit["human"]["judge_agreement"]["n_pairs"] == 1


def test_audit_names_annotation_of_unknown_episode(verdicts, sim_episodes):
    annotations = pd.DataFrame({"episode_a": ["a1"], "episode_b": ["zz"], "choice": ["A"]})
    with pytest.raises(ValueError, match=r"ann\.csv, row 0: episode zz has no sim rollout"):
        judge_audit(verdicts, sim_episodes, annotations=annotations, annotations_source="ann.csv", n_boot=100, **STATS, shuffled_permutations=20)


def test_audit_names_an_annotator_answering_a_pair_twice(verdicts, sim_episodes):
    annotations = pd.DataFrame({"episode_a": ["a1", "b1"], "episode_b": ["b1", "a1"], "choice": ["A", "A"],
                                "annotator": ["x", "x"]})
    with pytest.raises(ValueError, match=r"rows 0 and 1: annotator x answered episodes b1 / a1 twice"):
        judge_audit(verdicts, sim_episodes, annotations=annotations, n_boot=100, **STATS, shuffled_permutations=20)


def test_audit_rejects_bad_choice(verdicts, sim_episodes):
    annotations = pd.DataFrame({"episode_a": ["a1"], "episode_b": ["b1"], "choice": ["left"]})
    with pytest.raises(ValueError, match="choice must be A or B"):
        judge_audit(verdicts, sim_episodes, annotations=annotations, n_boot=100, **STATS, shuffled_permutations=20)


def test_win_rate_matrix_ordered_by_win_share(verdicts):
    rates = win_rate_matrix(verdicts)
    assert list(rates.index) == ["a", "b", "c"] and list(rates.columns) == ["a", "b", "c"]
    expected = np.array([[np.nan, 1.0, 0.5], [0.0, np.nan, 1.0], [0.5, 0.0, np.nan]])
    np.testing.assert_allclose(rates.to_numpy(), expected)


def test_case_study_picks_same_outcome_pair(verdicts, sim_episodes):
    case = pick_case_study(verdicts, sim_episodes, "success")
    assert case["n_candidates"] == 1
    assert case["preferred"]["episode_id"] == "a1" and case["other"]["episode_id"] == "b1"
    fail = pick_case_study(verdicts, sim_episodes, "failure")
    assert (fail["preferred"]["episode_id"], fail["other"]["episode_id"]) == ("b2", "c2")  # answered B
    assert pick_case_study(verdicts, sim_episodes, "any", rank=1)["preferred"]["episode_id"] == "b2"
    with pytest.raises(ValueError, match=r"no case study at rank 2: .*\{'any': 2\}"):
        pick_case_study(verdicts, sim_episodes, "any", rank=2)
    with pytest.raises(ValueError, match="outcomes must be success, failure or any"):
        pick_case_study(verdicts, sim_episodes, ["success", "both"])


def test_case_study_falls_back_to_the_next_outcome(verdicts, sim_episodes):
    sim_episodes["success"] = [True, True, False, False, False, False]  # only a's rollouts succeed
    case = pick_case_study(verdicts, sim_episodes, ["success", "failure"])
    assert case["outcome"] == "failure" and case["n_candidates"] == 2
    assert (case["preferred"]["episode_id"], case["other"]["episode_id"]) == ("b1", "c1")  # b/c pair 0, answered A


def test_case_study_without_candidates(verdicts, sim_episodes):
    sim_episodes["success"] = [True, True, False, False, False, False]  # only a's rollouts succeed
    with pytest.raises(ValueError, match=r"no case study at rank 0: .*\{'success': 0\}"):
        pick_case_study(verdicts, sim_episodes, "success")


def test_judge_averaged_scores(make_fit):
    fits = {
        "j1": make_fit({1: {"a": (90, 80, 95), "b": (10, 5, 20)}, 2: {"a": (70, 60, 80), "b": (30, 20, 40)}}),
        "j2": make_fit({2: {"a": (50, 40, 60), "b": (50, 40, 60)}}),
    }
    avg = judge_averaged_scores(fits)
    assert avg.loc["a", ["score", "ci_low", "ci_high"]].tolist() == pytest.approx([60, 50, 70])
    assert avg.loc["b", "score:j1"] == 30 and avg.loc["b", "score:j2"] == 50
    fits["j2"] = make_fit({2: {"a": (50, 40, 60)}})
    with pytest.raises(ValueError, match=r"judge j2: no score for policies \['b'\]"):
        judge_averaged_scores(fits)


def test_fit_interval_and_reference_interval(make_fit):
    from r2s_eval.report import fit_interval, reference_interval

    fit = make_fit({1: {"a": (60, 50, 70)}})
    assert fit_interval({"j": fit}) == ("binomial", 0.95)  # tables from before the unit bootstrap
    fit["interval"], fit["ci_level"] = "unit", 0.9
    assert fit_interval({"j": fit}) == ("unit", 0.9)
    ref = {"success_rate": {"a": 0.5}, "ci_low": {"a": 0.3}, "ci_high": {"a": 0.7}}
    assert reference_interval({"j2": {"reference": ref}, "j1": {}}) == {"a": (0.3, 0.7)}
    assert reference_interval({"j1": {"average": {}}}) == {}


# --------------------------------------------------------------- judge report card


def test_judge_card_outcome_and_planted_order_agreement(verdicts, sim_episodes):
    # Mixed-outcome pairs: a2>b2 (hit), c1 over a1 (miss), a2>c2 (hit), b1>c1 (hit), at inits 1, 0, 1, 0.
    audit = judge_audit(verdicts, sim_episodes, planted_order=["a", "b", "c"], n_boot=200, shuffled_permutations=0, **STATS)
    outcome = audit["outcome_agreement"]
    assert outcome["share"] == pytest.approx(0.75) and outcome["n_pairs"] == 4 and outcome["n_units"] == 2
    assert outcome["ci_low"] <= 0.75 <= outcome["ci_high"]
    # Pairs that both succeeded: a1 over b1, following a > b > c (b2 over c2, two failures, is not counted).
    planted = audit["planted_order_agreement"]
    assert planted["share"] == 1.0 and planted["n_pairs"] == 1 and planted["n_unranked_pairs"] == 0
    reverse = judge_audit(verdicts, sim_episodes, planted_order=["c", "b", "a"], n_boot=200, shuffled_permutations=0, **STATS)
    assert reverse["planted_order_agreement"]["share"] == 0.0
    partial = judge_audit(verdicts, sim_episodes, planted_order=["a", "c"], n_boot=200, shuffled_permutations=0, **STATS)
    assert partial["planted_order_agreement"]["share"] is None
    assert partial["planted_order_agreement"]["n_unranked_pairs"] == 1
    assert audit["shuffled_label_control"] is None


def test_judge_card_keeps_the_audit_keys_and_adds_counts(verdicts, sim_episodes):
    audit = judge_audit(verdicts, sim_episodes, n_boot=100, shuffled_permutations=3, **STATS)
    assert audit["a_share"] == pytest.approx(4 / 6) and audit["n_a_answers"] == 4
    assert audit["a_share_same_outcome"] == 0.5 and audit["n_same_outcome"] == 2 and audit["n_a_same_outcome"] == 1
    assert audit["swap_consistency"] is None and audit["n_swapped"] == 0 and audit["n_swap_consistent"] == 0
    assert audit["planted_order_agreement"] is None  # no order configured
    shuffled = audit["shuffled_label_control"]
    assert shuffled["policies"] == ["a", "b", "c"] and shuffled["n_permutations"] == 3
    assert 0.0 <= shuffled["permuted_flat_share"] <= 1.0
    assert set(shuffled["real"]) >= {"scores", "ci_low", "ci_high", "flat"}


def test_judge_card_counts_consistent_swaps(verdicts, sim_episodes):
    verdicts["swapped_verdict"] = ["B", "A", "A", "", None, "A"]  # consistent, consistent, not, -, -, consistent
    audit = judge_audit(verdicts, sim_episodes, swapped_letter_columns=["swapped_verdict"], n_boot=50,
                        shuffled_permutations=0, **STATS)
    assert audit["n_swapped"] == 4 and audit["n_swap_consistent"] == 3
    assert audit["swap_consistency"] == pytest.approx(0.75)
