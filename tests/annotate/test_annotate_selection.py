"""The annotation set: balance, task spread, honest shortfall, blinding, same bytes for the same seed."""

from __future__ import annotations

import pandas as pd
import pytest

from r2s_eval.annotate import CATEGORIES, candidate_pairs, draw_annotation_set, write_annotation_set
from r2s_eval.annotate.criteria import CRITERIA_TEXT
from r2s_eval.annotate.selection import SET_COLUMNS, category_targets, video_token
from r2s_eval.errors import DataError
from r2s_eval.judge.base import CRITERIA
from r2s_eval.utils.io import file_sha256


@pytest.fixture(scope="module")
def pairs(run):
    return pd.read_parquet(run["root"] / "results" / "compare" / "pairs.parquet")


def test_pool_is_distinct_video_pairs_with_their_outcome_category(run, pairs):
    pool = candidate_pairs(pairs, run["sim"])
    # 3 policy pairs x 2 tasks x 4 inits, one rollout per policy and init: 24 distinct pairs.
    assert len(pool) == 24 and pool["n_comparisons"].sum() == len(pairs)
    # alpha always succeeds, gamma never, beta on even inits.
    assert pool["category"].value_counts().to_dict() == {"success-failure": 16, "failure-failure": 4,
                                                          "success-success": 4}


def test_set_is_balanced_spread_over_tasks_and_same_task_and_init(run, pairs):
    items, summary = draw_annotation_set(pairs, run["sim"], n_pairs=12, seed=3)
    assert list(items.columns) == list(SET_COLUMNS)
    assert items.groupby("category").size().to_dict() == {c: 4 for c in CATEGORIES}
    for _, group in items.groupby("category"):
        assert group["task"].value_counts().tolist() == [2, 2]  # evenly over the two tasks
    episodes = run["sim"].set_index("episode_id")
    for row in items.itertuples():
        a, b = episodes.loc[row.episode_a], episodes.loc[row.episode_b]
        assert a.task == b.task == row.task and a.init_id == b.init_id == row.init_id
        assert a.policy == row.policy_a != row.policy_b == b.policy
        assert (a.success, b.success) == (row.success_a, row.success_b)
    assert summary["n_shortfall"] == 0 and summary["per_task"] == {"block_in_bin": 6, "cup_on_plate": 6}
    assert items["item_id"].is_unique and len({frozenset(p) for p in zip(items.episode_a, items.episode_b)}) == 12


def test_short_category_is_taken_whole_and_its_shortfall_recorded(run, pairs):
    items, summary = draw_annotation_set(pairs, run["sim"], n_pairs=30, seed=0)
    cats = summary["categories"]
    assert cats["success-success"] == {"target": 10, "available": 4, "drawn": 4, "shortfall": 6}
    assert cats["failure-failure"] == {"target": 10, "available": 4, "drawn": 4, "shortfall": 6}
    assert cats["success-failure"] == {"target": 10, "available": 16, "drawn": 10, "shortfall": 0}
    assert len(items) == summary["n_items"] == 18 and summary["n_shortfall"] == 12  # never topped up


def test_targets_split_the_count_evenly():
    assert category_targets(200) == {"success-success": 67, "failure-failure": 67, "success-failure": 66}
    assert sum(category_targets(7).values()) == 7


def test_order_shown_is_a_fresh_coin_per_pair_and_ids_carry_no_category(run, pairs):
    items, _ = draw_annotation_set(pairs, run["sim"], n_pairs=18, seed=0)
    judged_first = {(r.episode_a, r.episode_b) for r in pairs.itertuples()}
    kept = sum((r.episode_a, r.episode_b) in judged_first for r in items.itertuples())
    assert 0 < kept < len(items)  # some pairs are shown in the judge's order, some swapped
    assert not items["category"].is_monotonic_increasing and not items["category"].is_monotonic_decreasing
    # Mixed pairs: the successful rollout is A in some items and B in others.
    mixed = items[items["category"] == "success-failure"]
    assert 0 < mixed["success_a"].sum() < len(mixed)


def test_same_seed_same_set_other_seed_other_draw(run, pairs):
    a, _ = draw_annotation_set(pairs, run["sim"], n_pairs=9, seed=5)
    b, _ = draw_annotation_set(pairs, run["sim"], n_pairs=9, seed=5)
    c, _ = draw_annotation_set(pairs, run["sim"], n_pairs=9, seed=6)
    pd.testing.assert_frame_equal(a, b)
    assert not a[["episode_a", "episode_b"]].equals(c[["episode_a", "episode_b"]])


def test_videos_are_served_under_opaque_tokens_and_copied_byte_for_byte(run, annotation_set):
    items, folder = annotation_set["items"], annotation_set["dir"]
    source = run["sim"].set_index("episode_id")["video_path"]
    for side in ("a", "b"):
        for episode, token, fps in zip(items[f"episode_{side}"], items[f"video_{side}"], items[f"fps_{side}"]):
            assert token == video_token(episode, 0) and len(token) == len("0" * 20 + ".mp4")
            assert all(p not in token for p in ("alpha", "beta", "gamma")) and episode not in token
            assert file_sha256(folder / "videos" / token) == file_sha256(source[episode])
            assert fps == 10.0
    assert sorted(p.name for p in (folder / "videos").iterdir()) == sorted(set(items["video_a"]) | set(items["video_b"]))


def test_same_config_same_bytes(run, pairs, tmp_path):
    for name in ("one", "two"):
        items, summary = draw_annotation_set(pairs, run["sim"], n_pairs=9, seed=0)
        write_annotation_set(items, summary, run["sim"], set_path=tmp_path / name / "set.parquet",
                             videos_dir=tmp_path / name / "videos", summary_path=tmp_path / name / "summary.json")
    for f in ("set.parquet", "summary.json"):
        assert file_sha256(tmp_path / "one" / f) == file_sha256(tmp_path / "two" / f)


def test_bad_pairs_are_named(run, pairs):
    broken = pairs.copy()
    broken.loc[3, "episode_b"] = "nope"
    with pytest.raises(DataError, match=r"episode nope has no sim rollout"):
        draw_annotation_set(broken, run["sim"], n_pairs=6, seed=0)
    moved = pairs.copy()
    moved.loc[0, "init_id"] = 3
    with pytest.raises(DataError, match=r"but the pair says task .*, init 3"):
        candidate_pairs(moved, run["sim"])
    with pytest.raises(DataError, match="positive number of pairs"):
        draw_annotation_set(pairs, run["sim"], n_pairs=0, seed=0)


def test_criteria_shown_are_the_judges():
    assert tuple(CRITERIA_TEXT) == CRITERIA
