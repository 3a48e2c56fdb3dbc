"""Stability of a ranking over repeated evaluations, on planted tables."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from r2s_eval.errors import DataError
from r2s_eval.stats.stability import (
    adjacent_pairs,
    agreement,
    blocks,
    order_of,
    repeated,
    stability_summary,
    success_rates,
    truth_order,
)

VARIANTS = {"good_shaky": "good"}


def _trials(rates: dict[str, float], inits: int, tasks=("t1", "t2")) -> pd.DataFrame:
    """Real trials whose success share per task is exactly the rate (successes on the first inits
    of every block of ten, so every block of inits holds the same share)."""
    rows = []
    for policy, rate in rates.items():
        for task in tasks:
            for init in range(inits):
                rows.append({"policy": policy, "task": task, "init_id": init, "success": (init % 10) < round(10 * rate)})
    return pd.DataFrame(rows)


def test_the_truth_orders_planted_pairs_by_construction_and_the_rest_where_the_twin_is_clear():
    trials = _trials({"good": 0.6, "good_shaky": 0.6, "close": 0.5, "weak": 0.0}, inits=50)
    rate, se = success_rates(trials)
    assert rate["good"] == pytest.approx(0.6) and se["good"] == pytest.approx(np.sqrt(0.24 / 50) / np.sqrt(2))
    truth = truth_order(trials, VARIANTS, sorted(rate.index), z=1.96)
    assert truth[("good", "good_shaky")] == 1  # equal success: the clean run by construction
    assert truth[("close", "good")] == 0  # 10 points on 100 trials each: within 1.96 standard errors
    assert truth[("good", "weak")] == 1 and truth[("close", "weak")] == 1
    assert truth[("close", "good_shaky")] == 0


def test_agreement_counts_ties_half_and_skips_undecided_pairs():
    truth = {("a", "b"): 1, ("a", "c"): 1, ("b", "c"): 0}
    assert agreement({("a", "b"): 1, ("a", "c"): 1, ("b", "c"): -1}, truth) == {
        "decided_pairs": 2, "share": 1.0, "kendall_distance": 0.0, "equal": True}
    card = agreement({("a", "b"): -1, ("a", "c"): 0, ("b", "c"): 1}, truth)
    assert card["kendall_distance"] == 1.5 and card["share"] == 0.25 and card["equal"] is False
    assert order_of({"a": 2.0, "b": 1.0, "c": 2.0}) == {("a", "b"): 1, ("a", "c"): 0, ("b", "c"): -1}


def test_flip_rates_and_the_share_against_the_truth_over_repetitions():
    truth = {("a", "b"): 1, ("a", "c"): 1, ("b", "c"): 0}
    orders = [{("a", "b"): 1, ("a", "c"): 1, ("b", "c"): 1}] * 3 + [{("a", "b"): -1, ("a", "c"): 1, ("b", "c"): -1}]
    card = repeated(orders, [truth] * 4, [("a", "b"), ("b", "c")])
    assert card["repetitions"] == 4 and card["equal_share"] == 0.75 and card["kendall_distance"] == 0.25
    assert card["pairs"]["a vs b"] == {"flip_rate": 0.25, "against_truth": 0.25, "truth_decided": 4, "first_above": 3.0}
    # An undecided pair still has a flip rate (how stable its order is), but nothing against the truth.
    assert card["pairs"]["b vs c"]["flip_rate"] == 0.25 and card["pairs"]["b vs c"]["against_truth"] is None


def test_an_error_in_most_repetitions_is_reported_as_repeated():
    truth = {("a", "b"): 1, ("a", "c"): 1, ("b", "c"): -1}
    biased = {("a", "b"): -1, ("a", "c"): 1, ("b", "c"): -1}  # a below b: a bias, every time
    noisy = {("a", "b"): -1, ("a", "c"): 0, ("b", "c"): 1}
    card = repeated([biased, biased, {**biased, ("b", "c"): 1}, noisy, truth], [truth] * 5, [("a", "b")])
    # a vs b against the truth in 4 of 5; b vs c in 2; a vs c tied once (half an error).
    assert card["errors"] == {"a vs b": 4.0, "b vs c": 2.0, "a vs c": 0.5}
    assert card["repeated_errors"] == {"a vs b": 4.0}
    # A pair the truth leaves undecided is never an error.
    undecided = {**truth, ("b", "c"): 0}
    assert "b vs c" not in repeated([noisy] * 5, [undecided] * 5, [])["errors"]


def test_a_variant_sits_right_below_its_clean_candidate():
    rate = {"good": 0.6, "good_shaky": 0.62, "close": 0.58, "weak": 0.0}
    assert adjacent_pairs(rate, VARIANTS) == [("good", "good_shaky"), ("close", "good_shaky"), ("close", "weak")]
    rate["good_shaky"] = 0.3
    assert adjacent_pairs(rate, VARIANTS) == [("close", "good"), ("close", "good_shaky"), ("good_shaky", "weak")]


def test_a_judge_that_sees_quality_is_stable_where_a_small_real_evaluation_flips():
    k, per_block = 4, 10
    rates = {"good": 0.6, "good_shaky": 0.6, "weak": 0.1}
    real = _trials(rates, inits=k * per_block)
    # The real side of one block: `good_shaky` got lucky there (its first 10 inits of block 1 all succeed).
    real.loc[(real["policy"] == "good_shaky") & real["init_id"].between(10, 19), "success"] = True
    verdicts = []
    for init in range(k * per_block):
        for task in ("t1", "t2"):
            for pi, pj, winner in (("good", "good_shaky", "good"), ("good", "weak", "good"),
                                   ("good_shaky", "weak", "good_shaky"), ("good", "good_shaky", "good")):
                verdicts.append({"policy_i": pi, "policy_j": pj, "winner": winner, "task": task, "init_id": init})
    verdicts = pd.DataFrame(verdicts)
    # One upset per pair and block keeps every BT strength positive.
    for start in range(0, k * per_block, per_block):
        first = verdicts.index[verdicts["init_id"] == start][:3]
        verdicts.loc[first, "winner"] = ["good_shaky", "weak", "weak"]
    summary = stability_summary(real, {"kinematic": verdicts}, inits_per_task=k * per_block, repetitions=k,
                                real_trials_per_task=per_block, trials_curve=[5, 10], truth_z=1.96, variants=VARIANTS)
    judge, real10 = summary["evaluations"]["kinematic"], summary["evaluations"]["real 10"]
    assert judge["equal_share"] == 1.0 and judge["pairs"]["good vs good_shaky"]["flip_rate"] == 0.0
    # The real evaluation ties the planted pair on three blocks and reverses it on one.
    assert real10["pairs"]["good vs good_shaky"]["against_truth"] == pytest.approx((3 * 0.5 + 1) / 4)
    assert summary["behind_each_repetition"]["sim_rollouts_per_policy"] == 2 * per_block
    assert summary["behind_each_repetition"]["comparisons"]["kinematic"] == [per_block * 2 * 4] * k
    assert summary["truth"]["real_trials_per_policy"] == 2 * per_block * (k - 1)
    assert blocks(45, 4) == [range(0, 11), range(11, 22), range(22, 33), range(33, 44)]


def _close_above_good(inits: int) -> pd.DataFrame:
    """A judge's verdicts that put `close` above `good` (two of three) and both above `weak`."""
    verdicts = []
    for init in range(inits):
        for pi, pj, winner in (("close", "good", "close"), ("close", "good", "good"), ("close", "good", "close"),
                               ("good", "weak", "good"), ("close", "weak", "close"), ("good", "weak", "weak")):
            verdicts.append({"policy_i": pi, "policy_j": pj, "winner": winner, "task": "t1", "init_id": init})
    return pd.DataFrame(verdicts)


def test_the_sim_side_splits_a_judges_errors_into_the_sims_and_its_own():
    # `close` succeeds more than `good` in the sim and less in the real world: a judge that follows
    # the sim errs on that pair every time, and the sim's own success count errs with it.
    k, per_block = 4, 10
    real = _trials({"good": 0.6, "close": 0.3, "weak": 0.1}, inits=k * per_block)
    sim = _trials({"good": 0.4, "close": 0.7, "weak": 0.1}, inits=k * per_block)
    verdicts = _close_above_good(k * per_block)
    summary = stability_summary(real, {"kinematic": verdicts}, inits_per_task=k * per_block,
                                repetitions=k, real_trials_per_task=per_block, trials_curve=[10], truth_z=1.96,
                                variants={}, sim=sim)
    judge, counted = summary["evaluations"]["kinematic"], summary["evaluations"]["sim success"]
    assert judge["repeated_errors"] == {"close vs good": 4.0} == counted["repeated_errors"]
    # Against what the sim holds, the judge orders every decided pair right: the error is the sim's.
    own = summary["against_sim_truth"]["kinematic"]
    assert own["agreement"] == 1.0 and own["repeated_errors"] == {}
    assert summary["truth"]["sim_success_all_rollouts"] == pytest.approx({"close": 0.7, "good": 0.4, "weak": 0.1})
    # Without the sim, neither view is made.
    plain = stability_summary(real, {"kinematic": verdicts}, inits_per_task=k * per_block,
                              repetitions=k, real_trials_per_task=per_block, trials_curve=[10], truth_z=1.96, variants={})
    assert "sim success" not in plain["evaluations"] and "against_sim_truth" not in plain
    from r2s_eval.report.tables import stability_table
    table = stability_table(summary)
    assert "sim success" in table and "Against the sim's own truth" in table and "100.0" in table
    assert "Against the sim" not in stability_table(plain)


def test_the_networks_ranked_in_the_twin_split_the_training_from_the_sim_and_the_judges():
    # The sim ranks pi^S, the real truth is pi^R's: `close`'s pi^S is the better network in both
    # worlds, its pi^R the worse. Against the twin's success of the networks ranked, the sim's
    # count and the judge order every decided pair right: the error is the training's.
    k, per_block = 4, 10
    real = _trials({"good": 0.6, "close": 0.3, "weak": 0.1}, inits=k * per_block)
    sim = _trials({"good": 0.4, "close": 0.7, "weak": 0.1}, inits=k * per_block)
    in_twin = _trials({"good": 0.4, "close": 0.8, "weak": 0.0}, inits=k * per_block)
    verdicts = _close_above_good(k * per_block)
    args = dict(inits_per_task=k * per_block, repetitions=k, real_trials_per_task=per_block, trials_curve=[10],
                truth_z=1.96, variants={}, sim=sim)
    summary = stability_summary(real, {"kinematic": verdicts}, networks_in_twin=in_twin, **args)
    assert summary["evaluations"]["kinematic"]["repeated_errors"] == {"close vs good": 4.0}
    for name in ("kinematic", "sim success"):
        view = summary["against_networks_in_twin"][name]
        assert view["agreement"] == 1.0 and view["repeated_errors"] == {}
    assert summary["truth"]["networks_in_twin_success_all_rollouts"] == pytest.approx(
        {"close": 0.8, "good": 0.4, "weak": 0.0})
    from r2s_eval.report.tables import stability_table
    assert "Against the twin's truth of the networks ranked" in stability_table(summary)
    # A candidate whose weights come from elsewhere has no rollouts there: its pairs stay undecided.
    partial = stability_summary(real, {"kinematic": verdicts},
                                networks_in_twin=in_twin[in_twin["policy"] != "weak"], **args)
    assert partial["truth"]["networks_in_twin_left_out"] == ["weak"]
    assert summary["truth"]["networks_in_twin_left_out"] == []
    assert partial["against_networks_in_twin"]["kinematic"]["pairs"]["close vs weak"]["truth_decided"] == 0
    assert summary["against_networks_in_twin"]["kinematic"]["pairs"]["close vs weak"]["truth_decided"] == k


def test_each_repetition_ranks_from_its_share_of_the_sim_only_inits_too():
    # 30 inits per task on both sides, 30 more in the sim alone (rollout.real_inits_per_task 30 of
    # 60): repetition r holds real block r (10 inits) and sim-only inits 30 + 10r .. 39 + 10r. On the
    # real blocks' inits the judge prefers `weak` to `good` two times in three; on the sim-only ones
    # `good` always, twice as many comparisons: only a judge that sees those orders the pair.
    k, per_block = 3, 10
    real = _trials({"good": 0.6, "weak": 0.1}, inits=k * per_block)
    sim = _trials({"good": 0.6, "weak": 0.1}, inits=2 * k * per_block)
    sim.loc[(sim["policy"] == "weak") & (sim["init_id"] < k * per_block), "success"] = True  # the real blocks' luck
    verdicts = []
    for init in range(2 * k * per_block):
        sim_only = init >= k * per_block
        for winner in (("good", "good", "good", "good") if sim_only else ("weak", "weak", "good")):
            verdicts.append({"policy_i": "good", "policy_j": "weak", "winner": winner, "task": "t1", "init_id": init})
    verdicts = pd.DataFrame(verdicts)
    args = dict(repetitions=k, real_trials_per_task=per_block, trials_curve=[per_block], truth_z=1.96, variants={})
    summary = stability_summary(real, {"kinematic": verdicts}, inits_per_task=2 * k * per_block, sim=sim,
                                real_inits_per_task=k * per_block, **args)
    assert summary["inits_per_repetition_and_task"] == per_block
    assert summary["sim_inits_per_repetition_and_task"] == 2 * per_block
    assert summary["behind_each_repetition"]["sim_rollouts_per_policy"] == 2 * 2 * per_block
    assert summary["behind_each_repetition"]["comparisons"]["kinematic"] == [per_block * (3 + 4)] * k
    assert summary["truth"]["real_trials_per_policy"] == 2 * per_block * (k - 1)  # the real side's blocks alone
    assert summary["evaluations"]["kinematic"]["agreement"] == 1.0
    # The sim's success over a repetition's 20 inits: `weak` 55 % (lucky on the real block's 10), `good` 60 %.
    assert summary["evaluations"]["sim success"]["agreement"] == 1.0
    # Without the sim-only inits, each repetition sees the real block's inits alone, and the judge errs.
    alone = stability_summary(real, {"kinematic": verdicts}, inits_per_task=k * per_block, sim=sim, **args)
    assert alone["sim_inits_per_repetition_and_task"] == per_block
    assert alone["evaluations"]["kinematic"]["repeated_errors"] == {"good vs weak": 3.0}
    assert alone["evaluations"]["sim success"]["agreement"] == 0.0
    # A repetition without a comparison is named with its inits.
    with pytest.raises(DataError, match=r"repetition 1 \(10-19, 40-49\)"):
        stability_summary(real, {"kinematic": verdicts[~verdicts["init_id"].isin([*range(10, 20), *range(40, 50)])]},
                          inits_per_task=2 * k * per_block, real_inits_per_task=k * per_block, **args)


def test_the_interval_of_a_share_is_students_t_over_the_repetitions():
    from r2s_eval.stats.stability import repetition_interval
    low, high = repetition_interval([0.8, 0.9, 1.0, None], level=0.95)  # a repetition that decides nothing: left out
    assert low == pytest.approx(0.9 - 4.302653 * 0.1 / np.sqrt(3)) and high == 1.0  # clipped at 1
    assert repetition_interval([-0.2, -0.2], level=0.95, bounds=(-1, 1)) == [-0.2, -0.2]
    assert repetition_interval([0.7], level=0.95) is None  # one repetition has no spread to read


def test_each_share_has_its_interval_and_its_difference_from_the_real_evaluation_is_paired():
    k, per_block = 4, 10
    real = _trials({"good": 0.6, "close": 0.3, "weak": 0.1}, inits=k * per_block)
    real.loc[(real["policy"] == "weak") & (real["init_id"] % 10 == 9), "success"] = True  # weak 0.2: closer to close
    verdicts = _close_above_good(k * per_block)  # a judge that puts close above good, every time
    args = dict(inits_per_task=k * per_block, repetitions=k, real_trials_per_task=per_block, trials_curve=[5, 10],
                truth_z=1.96, variants={})
    summary = stability_summary(real, {"kinematic": verdicts}, sim=real, level=0.9, **args)
    cards, beside_real = summary["evaluations"], summary["beside_real"]
    assert beside_real["reference"] == "real 10" and beside_real["level"] == 0.9
    assert "real 10" not in beside_real["differences"]
    # The sim here is the real trials themselves: in every repetition it ranks as the real evaluation does.
    assert beside_real["differences"]["sim success"] == {"difference": 0.0, "repetitions": k, "interval": [0.0, 0.0]}
    # The judge errs on close vs good in every repetition, by the same share: its interval says so.
    judge = beside_real["differences"]["kinematic"]
    shares = [c["share"] for c in cards["kinematic"]["per_repetition"]]
    assert judge["difference"] == pytest.approx(cards["kinematic"]["agreement"] - cards["real 10"]["agreement"])
    assert judge["difference"] < 0
    assert judge["interval"] == pytest.approx([judge["difference"]] * 2)
    assert cards["kinematic"]["agreement_interval"] == pytest.approx([np.mean(shares)] * 2)
    plain = stability_summary(real, {"kinematic": verdicts}, sim=real, **args)
    assert "beside_real" not in plain and "agreement_interval" not in plain["evaluations"]["kinematic"]
    from r2s_eval.report.tables import stability_table
    table = stability_table(summary)
    assert r"90 \% interval" in table and r"minus real 10 [90 \%]" in table
    assert f"{100 * judge['difference']:+.1f} [{100 * judge['difference']:+.1f}, {100 * judge['difference']:+.1f}]" in table
    assert r"90 \% interval" not in stability_table(plain)


def test_the_stability_figure_draws_each_rankings_interval_or_else_its_range():
    """The judges' bars span ``agreement_interval`` where the summary holds one (here wider than the
    repetitions' range), else the range; the title says which, and what the sim's points rank from."""
    from pathlib import Path

    from matplotlib.collections import LineCollection

    from r2s_eval.config import compose_config
    from r2s_eval.report.figures import stability_figure

    def card(shares, interval=None):
        return {"per_repetition": [{"share": s} for s in shares],
                **({"agreement_interval": interval} if interval else {})}

    opts = compose_config(Path(__file__).resolve().parents[2] / "conf", experiment="smoke")["report"]["stability"]
    shares = [0.5, 0.7, 0.9]
    for interval, level, title, expected in (([0.2, 1.0], 0.95, "95 % intervals", [20, 100]),
                                             (None, None, "their range", [50, 90])):
        summary = {"repetitions": 3, "policies": ["a", "b", "c"], "sim_inits_per_repetition_and_task": 15,
                   "evaluations": {"real 5": card([0.6, 0.8, 1.0], interval), "kinematic": card(shares, interval)},
                   **({"beside_real": {"level": level}} if level else {})}
        ax = stability_figure(summary, opts).axes[0]
        assert title in ax.get_title() and "from 15 sim rollouts per task and policy" in ax.get_title()
        bars = [c for c in ax.collections if isinstance(c, LineCollection)]  # the judge's error bar
        assert sorted(float(p[1]) for seg in bars[-1].get_segments() for p in seg) == pytest.approx(expected)
