"""The cross-evaluation split: calibration and training parts that add up to the method's gap."""

from __future__ import annotations

import pandas as pd
import pytest

from r2s_eval.stats.fidelity import PARTS, cross_evaluation, same_policy_agreement, seed_spread


def table(rows):
    return pd.DataFrame(rows, columns=["policy", "task", "successes", "trials"])


WORLDS = {
    "R_real": table([("a", "t1", 12, 20), ("a", "t2", 10, 20), ("b", "t1", 4, 20), ("b", "t2", 2, 20)]),
    "R_sim": table([("a", "t1", 9, 20), ("a", "t2", 11, 20), ("b", "t1", 5, 20), ("b", "t2", 1, 20)]),
    "S_sim": table([("a", "t1", 7, 20), ("a", "t2", 8, 20), ("b", "t1", 6, 20), ("b", "t2", 0, 20)]),
    "S_real": table([("a", "t1", 8, 20), ("a", "t2", 9, 20), ("b", "t1", 3, 20), ("b", "t2", 1, 20)]),
}


def gaps(report, part):
    return {(c["policy"], c["task"]): c["gap_pp"] for c in report["parts"][part]["cells_gap_pp"]}


def test_calibration_and_training_add_up_to_the_total_per_cell():
    report = cross_evaluation(WORLDS, level=0.95, n_boot=200, seed=0)
    assert set(report["parts"]) == set(PARTS)
    total, calibration, training = gaps(report, "total"), gaps(report, "calibration"), gaps(report, "training")
    for cell in total:
        assert total[cell] == pytest.approx(calibration[cell] + training[cell])
    assert calibration[("a", "t1")] == pytest.approx(100 * (9 - 12) / 20)
    part = report["parts"]["calibration"]
    assert part["compares"] == "R_sim - R_real" and part["cells"] == 4
    assert part["mean_abs_gap_ci_pp"][0] <= part["mean_abs_gap_pp"] <= part["mean_abs_gap_ci_pp"][1]
    cell = next(c for c in report["cells"] if (c["policy"], c["task"]) == ("b", "t2"))
    assert cell["S_real"] == {"rate": 0.05, "ci": pytest.approx(cell["S_real"]["ci"]), "successes": 1, "trials": 20}
    assert cell["S_real"]["ci"][0] < 0.05 < cell["S_real"]["ci"][1]


def test_without_the_real_side_for_pi_S_only_its_parts_are_left_out():
    worlds = {**WORLDS, "S_real": None}
    report = cross_evaluation(worlds, level=0.95, n_boot=100, seed=0)
    assert set(report["parts"]) == {"calibration", "training", "total"}
    assert all("S_real" not in c for c in report["cells"])


def test_same_policy_agreement_scores_each_sim_against_the_real_side():
    agreement = same_policy_agreement(WORLDS)
    assert agreement["R_sim"]["policies"] == ["a", "b"]
    assert agreement["R_sim"]["pearson"] == pytest.approx(1.0)  # two policies, same order
    assert agreement["R_sim"]["mmrv_pp"] == 0.0
    swapped = {**WORLDS, "R_sim": table([("a", "t1", 1, 20), ("b", "t1", 9, 20)])}
    assert same_policy_agreement(swapped)["R_sim"]["mmrv_pp"] > 0


def test_seed_spread_lists_every_seed_and_its_range():
    rows = seed_spread({"S_sim": {0: table([("a", "t1", 5, 10)]), 1: table([("a", "t1", 8, 10)]),
                                  2: table([("a", "t1", 6, 10)])}})
    assert rows == [{"world": "S_sim", "policy": "a", "task": "t1", "seeds": [0, 1, 2],
                     "rates_pct": [50.0, 80.0, 60.0], "range_pp": 30.0, "std_pp": pytest.approx(15.275, abs=1e-3)}]


def test_parts_whose_two_worlds_have_their_episodes_are_paired_over_the_shared_inits():
    def trials(successes, n=20):  # one cell's episodes: init i succeeds for the first `successes`
        return [("a", "t1", i, i < successes) for i in range(n)]

    def frame(rows):
        return pd.DataFrame(rows, columns=["policy", "task", "init_id", "success"])

    episodes = {"R_sim": frame(trials(9)), "S_sim": frame(trials(7)), "S_real": frame(trials(8))}
    worlds = {"R_real": table([("a", "t1", 12, 20)]), **{w: table([("a", "t1", 0, 0)]) for w in episodes}}
    for world, e in episodes.items():
        worlds[world] = table([("a", "t1", int(e["success"].sum()), len(e))])
    report = cross_evaluation(worlds, level=0.95, n_boot=200, seed=0, episodes=episodes)
    parts = report["parts"]
    # R_real is known only by its counts: the parts it is in are drawn on each side's own
    assert not parts["calibration"]["paired"] and not parts["total"]["paired"]
    assert parts["training"]["paired"] and parts["calibration_reverse"]["paired"]
    # nested outcomes (an init S_sim solves R_sim solves too): every redraw keeps the gap's sign
    assert parts["training"]["mean_gap_pp"] == pytest.approx(-10.0) and parts["training"]["mean_gap_ci_pp"][1] <= 0
    with_real = cross_evaluation(worlds | {"R_real": table([("a", "t1", 12, 20)])}, 0.95, 200, 0,
                                 {**episodes, "R_real": frame(trials(12))})
    assert with_real["parts"]["calibration"]["paired"]
    assert with_real["parts"]["calibration"]["mean_gap_ci_pp"][1] <= 0
