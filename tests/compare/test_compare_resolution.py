"""The resolution sweep's plan: one variant per kind and level, and the clean run paired with each
level's run from the same (task, init), its side drawn per comparison."""

from __future__ import annotations

import pandas as pd
import pytest

from r2s_eval.compare.resolution import SWEEP_COLUMNS, sweep_levels, sweep_pairs, with_key
from r2s_eval.compare.sampling import PAIR_COLUMNS
from r2s_eval.errors import DataError

RESOLUTION = {
    "policy": "act",
    "kinds": ["stops", "jitter"],
    "sweeps": {
        "jitter": {"key": "action_noise_std", "levels": [0.01, 0.04]},
        "stops": {"execution": {"hesitate": {"every_steps": 10, "pause_steps": 1}}, "key": "hesitate.pause_steps",
                  "levels": [2, 5, 8]},
        "unused": {"key": "lowpass", "levels": [0.5]},
    },
    "detect_share": 0.8,
}


def test_levels_follow_the_kinds_order_and_set_the_key_on_the_weakest_change():
    levels = sweep_levels(RESOLUTION)
    assert [lv.policy for lv in levels] == ["act.stops.1", "act.stops.2", "act.stops.3", "act.jitter.1", "act.jitter.2"]
    assert levels[1].execution == {"hesitate": {"every_steps": 10, "pause_steps": 5}}
    assert levels[3].execution == {"action_noise_std": 0.01}
    assert levels[1].variant("act") == {"type": "variant", "of": "act", "execution": levels[1].execution}
    # The sweep's entry is not changed by a level.
    assert RESOLUTION["sweeps"]["stops"]["execution"]["hesitate"]["pause_steps"] == 1
    assert sweep_levels({**RESOLUTION, "policy": None}) == []


def test_with_key_refuses_a_key_through_a_value():
    with pytest.raises(DataError, match="not a mapping"):
        with_key({"lowpass": 0.5}, "lowpass.depth", 1)


def _episodes(policies, inits=range(8), tasks=("cup_on_plate", "ball_in_box")):
    rows = [{"episode_id": f"{p}-{t}-{i}", "policy": p, "task": t, "init_id": i}
            for p in policies for t in tasks for i in inits]
    return pd.DataFrame(rows)


def test_pairs_match_inits_and_draw_sides_per_comparison():
    levels = sweep_levels(RESOLUTION)
    eps = _episodes(["act", *(lv.policy for lv in levels)])
    eps = eps[~((eps["policy"] == "act.jitter.2") & (eps["init_id"] == 7))]  # a level that missed an init
    pairs = sweep_pairs(eps, "act", levels, seed=3)
    assert list(pairs.columns) == [*PAIR_COLUMNS, *SWEEP_COLUMNS]
    assert len(pairs) == 5 * 16 - 2
    for row in pairs.itertuples():
        clean, changed = (row.episode_a, row.episode_b) if row.clean_side == "A" else (row.episode_b, row.episode_a)
        assert clean == f"act-{row.task}-{row.init_id}"
        assert changed == f"{row.policy_j}-{row.task}-{row.init_id}"
        assert {row.policy_a, row.policy_b} == {"act", row.policy_j}
    assert 0.3 < (pairs["clean_side"] == "A").mean() < 0.7
    # A comparison keeps its side whatever else the sweep holds; another seed draws others.
    alone = sweep_pairs(eps, "act", levels[3:4], seed=3)
    merged = alone.merge(pairs, on=["policy_j", "task", "init_id"], suffixes=("", "_all"))
    assert (merged["clean_side"] == merged["clean_side_all"]).all()
    assert not sweep_pairs(eps, "act", levels, seed=4)["clean_side"].equals(pairs["clean_side"])


def test_a_missing_run_is_named():
    levels = sweep_levels(RESOLUTION)
    with pytest.raises(DataError, match="act.jitter.2"):
        sweep_pairs(_episodes(["act", *(lv.policy for lv in levels[:-1])]), "act", levels, seed=0)
    with pytest.raises(DataError, match="clean candidate 'act'"):
        sweep_pairs(_episodes([lv.policy for lv in levels]), "act", levels, seed=0)
