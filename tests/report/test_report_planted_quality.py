"""Planted quality on the judge's report card: a scripted judge's verdicts on a variant and the
candidate whose weights it runs."""

from __future__ import annotations

import pandas as pd

from r2s_eval.report.summaries import planted_quality
from r2s_eval.report.tables import judge_card_table


def _verdicts(prefers_clean: list[bool], outcomes: list[tuple[bool, bool]]):
    rows, success = [], {}
    for k, (clean_wins, (clean_ok, variant_ok)) in enumerate(zip(prefers_clean, outcomes)):
        success[f"c{k}"], success[f"v{k}"] = clean_ok, variant_ok
        first_is_clean = k % 2 == 0  # both orders, as the pairs are drawn
        a, b = (f"c{k}", f"v{k}") if first_is_clean else (f"v{k}", f"c{k}")
        pi, pj = ("act", "act_shaky") if first_is_clean else ("act_shaky", "act")
        winner = "act" if clean_wins else "act_shaky"
        rows.append({"episode_a": a, "episode_b": b, "policy_i": pi, "policy_j": pj, "winner": winner,
                     "verdict": "A" if (winner == pi) else "B", "task": "cup_on_plate", "init_id": k})
    # A comparison of two other candidates is not part of the variant's card.
    rows.append({"episode_a": "c0", "episode_b": "x", "policy_i": "act", "policy_j": "act_weak", "winner": "act",
                 "verdict": "A", "task": "cup_on_plate", "init_id": 0})
    success["x"] = success["c0"]
    return pd.DataFrame(rows), success


def test_the_share_counts_pairs_that_both_succeeded_only_and_says_what_it_rests_on():
    # Two failures are compared by how far each got, not how it moved: they are not quality evidence.
    prefers = [True] * 8 + [False] * 2 + [False] * 6 + [False] * 4
    outcomes = [(True, True)] * 10 + [(False, False)] * 6 + [(True, False)] * 4  # the last four: mixed
    verdicts, success = _verdicts(prefers, outcomes)
    fit = pd.DataFrame({"checkpoint": [16] * 3, "policy": ["act", "act_shaky", "act_weak"],
                        "score": [60.0, 30.0, 10.0], "ci_low": [50.0, 22.0, 5.0], "ci_high": [70.0, 41.0, 15.0]})
    [card] = planted_quality(verdicts, success, {"act_shaky": "act"}, fit=fit,
                             reference_ci={"act": (0.30, 0.50), "act_shaky": (0.28, 0.47)},
                             n_boot=500, level=0.95, seed=1)
    assert (card["variant"], card["clean"]) == ("act_shaky", "act")
    assert card["n_pairs"] == 10 and card["n_units"] == 10 and card["n_pair_verdicts"] == 20
    assert card["share"] == 8 / 10 and card["ci_low"] < 0.8 < card["ci_high"] <= 1.0
    assert card["bt_separated"] is True and card["success_overlap"] is True
    # Apart in BT only when the clean interval lies above the variant's.
    fit.loc[fit["policy"] == "act_shaky", "ci_high"] = 55.0
    [card] = planted_quality(verdicts, success, {"act_shaky": "act"}, fit=fit, n_boot=100, level=0.95, seed=1)
    assert card["bt_separated"] is False and "success_overlap" not in card


def test_the_card_table_gains_a_row_per_judge_and_variant():
    verdicts, success = _verdicts([True, True, False, True], [(True, True)] * 4)
    card = planted_quality(verdicts, success, {"act_shaky": "act"}, n_boot=100, level=0.95, seed=0)
    table = judge_card_table({"kinematic": {"planted_quality": card}, "video": {"planted_quality": card}})
    rows = [line for line in table.splitlines() if "act\\_shaky vs act" in line]
    assert len(rows) == 2 and rows[0].startswith("kinematic") and "75.0" in rows[0] and "(4)" in rows[0]
    assert "Planted quality" in table
    # Without variants the card is the table it was.
    assert "Variant vs clean" not in judge_card_table({"kinematic": {"planted_quality": []}})
