"""A judge's resolution per level: the clean-preferred share on pairs that both succeeded, the successful
run's share where outcomes differ, success in both worlds, and where each kind is first seen."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from r2s_eval.compare.resolution import sweep_levels, sweep_pairs
from r2s_eval.errors import DataError
from r2s_eval.stats.resolution import kind_summaries, level_rows

RESOLUTION = {"policy": "act", "kinds": ["jitter"], "detect_share": 0.8,
              "sweeps": {"jitter": {"key": "action_noise_std", "levels": [0.005, 0.01, 0.04]}}}
N = 40


def _world(success_of) -> pd.DataFrame:
    """Episodes of the clean run and the three levels on N inits; success_of(policy, init)."""
    policies = ["act", "act.jitter.1", "act.jitter.2", "act.jitter.3"]
    return pd.DataFrame([{"episode_id": f"{p}-{i}", "policy": p, "task": "t", "init_id": i,
                          "success": bool(success_of(p, i))} for p in policies for i in range(N)])


def _verdicts(pairs: pd.DataFrame, clean_wins) -> pd.DataFrame:
    """The pairs with a winner: the clean run where clean_wins(row) holds."""
    out = pairs.copy()
    out["winner"] = [r.policy_i if clean_wins(r) else r.policy_j for r in pairs.itertuples()]
    return out


def test_shares_success_and_the_smallest_level_seen():
    levels = sweep_levels(RESOLUTION)
    # Level 3 fails everywhere in both worlds (quality became failure); the others keep success.
    sim = _world(lambda p, i: i % 2 == 0 and p != "act.jitter.3")
    real = _world(lambda p, i: i % 3 == 0 and p != "act.jitter.3")
    pairs = sweep_pairs(sim, "act", levels, seed=0)
    # The judge sees level 1 on half the pairs, levels 2 and 3 on all; it always prefers a success.
    # Only pairs that both succeeded (even inits) count: two failures are compared by progress.
    def clean_wins(r):
        ok = {e: s for e, s in zip(sim["episode_id"], sim["success"])}
        clean_ep, other = (r.episode_a, r.episode_b) if r.clean_side == "A" else (r.episode_b, r.episode_a)
        if ok[clean_ep] != ok[other]:
            return ok[clean_ep]
        return r.level > 1 or r.init_id % 4 == 0

    rows = level_rows(_verdicts(pairs, clean_wins), sim, real, "act", levels, detect_share=0.8, n_boot=200,
                      ci_level=0.95, seed=0)
    one, two, three = rows
    assert one["both_succeeded"]["n_pairs"] == N // 2 and one["both_succeeded"]["share"] == pytest.approx(0.5)
    assert one["both_failed"] == N // 2
    assert not one["detects"]
    assert two["both_succeeded"]["share"] == 1.0 and two["detects"] and two["success_kept"]
    assert one["different_outcome"]["n_pairs"] == 0 and one["different_outcome"]["share"] is None
    # Level 3: half the pairs differ in outcome (the clean run succeeded), the judge took the success.
    assert three["different_outcome"]["n_pairs"] == N // 2 and three["different_outcome"]["share"] == 1.0
    assert three["both_failed"] == N // 2 and three["both_succeeded"]["n_pairs"] == 0
    assert three["success"]["sim"]["changed"]["rate"] == 0.0 and three["success"]["real"]["clean"]["successes"] == 14
    assert three["success_kept"] is False
    assert kind_summaries(rows) == {"jitter": {"key": "action_noise_std", "smallest_detected": 2,
                                               "smallest_detected_success_kept": 2, "best_level": 2}}


def test_without_real_trials_success_is_the_sims_alone():
    levels = sweep_levels(RESOLUTION)
    sim = _world(lambda p, i: True)
    rows = level_rows(_verdicts(sweep_pairs(sim, "act", levels, seed=0), lambda r: True), sim, None, "act", levels,
                      detect_share=0.8, n_boot=100, ci_level=0.95, seed=0)
    assert all(r["success"]["real"] is None and r["success_kept"] is True and r["detects"] for r in rows)
    assert kind_summaries(rows)["jitter"]["smallest_detected"] == 1


def test_a_judge_that_never_sees_the_change_is_not_credited():
    levels = sweep_levels(RESOLUTION)
    sim = _world(lambda p, i: i % 2 == 0)
    rng = np.random.default_rng(0)
    coin = {(lv.policy, i): rng.random() < 0.5 for lv in levels for i in range(N)}
    rows = level_rows(_verdicts(sweep_pairs(sim, "act", levels, seed=0), lambda r: coin[(r.policy_j, r.init_id)]),
                      sim, sim, "act", levels, detect_share=0.8, n_boot=200, ci_level=0.95, seed=0)
    assert not any(r["detects"] for r in rows)
    summary = kind_summaries(rows)["jitter"]
    assert summary["smallest_detected"] is None and summary["best_level"] in (1, 2, 3)


def test_verdicts_on_episodes_without_a_success_record_are_refused():
    levels = sweep_levels(RESOLUTION)
    sim = _world(lambda p, i: True)
    verdicts = _verdicts(sweep_pairs(sim, "act", levels, seed=0), lambda r: True)
    with pytest.raises(DataError, match="without a success record"):
        level_rows(verdicts, sim[sim["policy"] != "act.jitter.2"], None, "act", levels, detect_share=0.8,
                   n_boot=10, ci_level=0.95, seed=0)
