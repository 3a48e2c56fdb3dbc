"""The reference table: counts per policy and task from rollout folders or a CSV of trials."""

from __future__ import annotations

import pandas as pd
import pytest

from r2s_eval.errors import DataError
from r2s_eval.stats.reference_table import reference_table


def test_reference_from_rollouts_counts_per_policy_and_task_sorted(tmp_path):
    for name, policy, successes in (("b", "dp", [True, False, False]), ("a", "act", [True, True])):
        (tmp_path / name).mkdir()
        pd.DataFrame({"policy": policy, "task": ["t2", "t1", "t1"][:len(successes)],
                      "success": successes}).to_parquet(tmp_path / name / "episodes.parquet")
    table = reference_table(rollout_dirs=[str(tmp_path / "b"), str(tmp_path / "a")])
    assert table[["policy", "task", "trials", "successes"]].values.tolist() == [
        ["act", "t1", 1, 1], ["act", "t2", 1, 1], ["dp", "t1", 2, 0], ["dp", "t2", 1, 1]]
    assert table["success_rate"].tolist() == [1.0, 1.0, 0.0, 1.0] and list(table.index) == [0, 1, 2, 3]


def test_reference_from_csv_keeps_its_counts_and_refuses_impossible_ones(tmp_path):
    good = tmp_path / "good.csv"
    pd.DataFrame({"policy": ["b", "a"], "task": "t", "trials": [4, 2], "successes": [1, 2], "note": "x"}).to_csv(good)
    table = reference_table(csv=str(good), rollout_dirs=["ignored"])
    assert list(table.columns) == ["policy", "task", "trials", "successes", "success_rate"]
    assert table["policy"].tolist() == ["a", "b"] and table["success_rate"].tolist() == [1.0, 0.25]
    bad = tmp_path / "bad.csv"
    pd.DataFrame({"policy": ["a"], "task": "t", "trials": [2], "successes": [3]}).to_csv(bad)
    with pytest.raises(DataError, match=r"bad.csv: impossible counts for \[\['a', 't'\]\]"):
        reference_table(csv=str(bad))
    with pytest.raises(DataError, match=r"missing column\(s\) \['successes'\]"):
        pd.DataFrame({"policy": ["a"], "task": "t", "trials": [2]}).to_csv(bad)
        reference_table(csv=str(bad))
