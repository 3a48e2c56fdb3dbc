"""Task-stratified, init-matched, side-balanced, nested pair sampling."""

from __future__ import annotations

import hashlib
from itertools import combinations

import numpy as np
import pandas as pd
import pytest

from r2s_eval.compare import PAIR_COLUMNS, sample_pairs

POLICIES = ["pi0", "act", "diffusion", "smolvla"]
TASKS = ["lift", "stack", "handover"]


def episode_table(policies=POLICIES, tasks=TASKS, inits=range(5), repeats=1, drop=()) -> pd.DataFrame:
    """One row per (policy, task, init, repeat); `drop` removes (policy, task, init) combinations."""
    rows = []
    for p in policies:
        for t in tasks:
            for i in inits:
                if (p, t, i) in drop:
                    continue
                for r in range(repeats):
                    rows.append({
                        "episode_id": hashlib.sha1(f"{p}/{t}/{i}/{r}".encode()).hexdigest()[:12], "policy": p, "arm": "sim", "task": t,
                        "instruction": f"do {t}", "init_id": i, "seed": r, "success": True, "length": 10,
                        "video_path": "v.mp4", "trajectory_path": "t.parquet",
                    })
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def episodes():
    return episode_table(repeats=2)


@pytest.fixture(scope="module")
def pairs(episodes):
    return sample_pairs(episodes, POLICIES, [5, 20, 50], seed=7)


def test_compare_columns_and_sizes(pairs):
    assert list(pairs.columns) == list(PAIR_COLUMNS)
    assert len(pairs) == 6 * 50
    for (pi, pj), g in pairs.groupby(["policy_i", "policy_j"]):
        assert POLICIES.index(pi) < POLICIES.index(pj)
        assert g["pair_index"].tolist() == list(range(50))
        assert set(g["policy_a"]) | set(g["policy_b"]) == {pi, pj}
        assert (g["policy_a"] != g["policy_b"]).all()
    assert {tuple(k) for k in pairs[["policy_i", "policy_j"]].drop_duplicates().values} == set(combinations(POLICIES, 2))


def test_compare_every_prefix_is_task_and_side_balanced(pairs):
    for _, g in pairs.groupby(["policy_i", "policy_j"]):
        g = g.sort_values("pair_index")
        onehot = pd.get_dummies(g["task"]).reindex(columns=TASKS, fill_value=False).to_numpy(int)
        counts = np.cumsum(onehot, axis=0)
        assert (counts.max(axis=1) - counts.min(axis=1) <= 1).all()
        i_is_a = np.cumsum((g["policy_a"] == g["policy_i"]).to_numpy())
        m = np.arange(1, len(g) + 1)
        assert (np.abs(i_is_a - m / 2) <= 1).all()
        assert 0 < i_is_a[-1] < len(g)


def test_compare_same_init_for_both_sides(pairs, episodes):
    ep = episodes.set_index("episode_id")
    a, b = ep.loc[pairs["episode_a"]], ep.loc[pairs["episode_b"]]
    assert (a["init_id"].to_numpy() == pairs["init_id"].to_numpy()).all()
    assert (b["init_id"].to_numpy() == pairs["init_id"].to_numpy()).all()
    assert (a["task"].to_numpy() == pairs["task"].to_numpy()).all() and (b["task"].to_numpy() == pairs["task"].to_numpy()).all()
    assert (a["policy"].to_numpy() == pairs["policy_a"].to_numpy()).all()
    assert (b["policy"].to_numpy() == pairs["policy_b"].to_numpy()).all()
    assert pairs["init_id"].nunique() > 1  # inits are drawn, not fixed


def test_compare_each_shared_init_once_before_any_twice(pairs):
    # 50 comparisons over 3 tasks of 5 inits: per pair and task, the inits come in rounds of all
    # five (a repeat of the same rollout pair adds no evidence until every other one is compared).
    for _, g in pairs.groupby(["policy_i", "policy_j", "task"]):
        inits = g.sort_values("pair_index")["init_id"].tolist()
        for start in range(0, len(inits), 5):
            one_round = inits[start:start + 5]
            assert len(set(one_round)) == len(one_round)
            if len(one_round) == 5:
                assert set(one_round) == set(range(5))


def test_compare_checkpoints_are_nested_prefixes(pairs, episodes):
    small = sample_pairs(episodes, POLICIES, [5], seed=7)
    pd.testing.assert_frame_equal(
        small.drop(columns="first_checkpoint"),
        pairs[pairs["pair_index"] < 5].drop(columns="first_checkpoint").reset_index(drop=True),
    )
    expected = np.select([pairs["pair_index"] < 5, pairs["pair_index"] < 20], [5, 20], 50)
    assert (pairs["first_checkpoint"].to_numpy() == expected).all()
    # Each comparison of a pair appears once: no pair is judged twice.
    assert not pairs.duplicated(["policy_i", "policy_j", "pair_index"]).any()


def test_compare_deterministic_for_a_seed(pairs, episodes):
    pd.testing.assert_frame_equal(pairs, sample_pairs(episodes, POLICIES, [5, 20, 50], seed=7))
    shuffled = episodes.sample(frac=1.0, random_state=1)
    pd.testing.assert_frame_equal(pairs, sample_pairs(shuffled, POLICIES, [50, 20, 5], seed=7))
    other = sample_pairs(episodes, POLICIES, [5, 20, 50], seed=8)
    assert not other[["task", "init_id", "policy_a"]].equals(pairs[["task", "init_id", "policy_a"]])


def test_compare_adding_a_policy_keeps_other_pairs(episodes, pairs):
    fewer = sample_pairs(episodes, POLICIES[:3], [5, 20, 50], seed=7)
    same = pairs[pairs["policy_j"] != POLICIES[3]].reset_index(drop=True)
    pd.testing.assert_frame_equal(fewer, same)


def test_compare_only_common_inits_are_used():
    # 'act' lacks inits 0-2 of 'stack', 'pi0' lacks init 4 of 'stack': only init 3 is shared there.
    drop = {("act", "stack", i) for i in range(3)} | {("pi0", "stack", 4)}
    df = episode_table(policies=["pi0", "act"], drop=drop)
    pairs = sample_pairs(df, ["pi0", "act"], [30], seed=0)
    assert set(pairs.loc[pairs["task"] == "stack", "init_id"]) == {3}
    lift = set(pairs.loc[pairs["task"] == "lift", "init_id"])
    assert lift <= set(range(5)) and len(lift) > 1


def test_compare_error_names_pair_and_task_without_common_init():
    drop = {("act", "handover", i) for i in range(3)} | {("pi0", "handover", i) for i in range(3, 5)}
    df = episode_table(policies=["pi0", "act", "diffusion"], drop=drop)
    with pytest.raises(ValueError, match=r"'pi0' and 'act' share no initial configuration .* task 'handover'"):
        sample_pairs(df, ["pi0", "act", "diffusion"], [10], seed=0)


def test_compare_input_errors(episodes):
    with pytest.raises(ValueError, match=r"policies \['ghost'\] have no episodes"):
        sample_pairs(episodes, ["pi0", "ghost"], [10], seed=0)
    with pytest.raises(ValueError, match="at least two distinct"):
        sample_pairs(episodes, ["pi0", "pi0"], [10], seed=0)
    with pytest.raises(ValueError, match="positive integers"):
        sample_pairs(episodes, POLICIES, [0, 10], seed=0)
    mixed = pd.concat([episodes, episodes.assign(arm="real", episode_id=episodes["episode_id"] + "r")])
    with pytest.raises(ValueError, match="mixes arms"):
        sample_pairs(mixed, POLICIES, [10], seed=0)
