"""The reference table a ranking is validated against: per policy and task, the trials and
successes of the real side, with the success rate, sorted by policy and task.

From closed-loop rollouts on the real side (the twin, or a robot logged the same way), or from
a CSV of hardware trials with columns policy, task, trials, successes. The table stays per task:
a policy's reference performance and its interval are computed from these counts where they are
used (``r2s_eval.stats.reference``).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.errors import DataError


def from_rollouts(rollout_dirs: list[str]) -> pd.DataFrame:
    """Trials and successes per (policy, task) of the rollout folders' episodes."""
    frames = [pd.read_parquet(Path(d) / "episodes.parquet") for d in rollout_dirs]
    episodes = pd.concat(frames, ignore_index=True)
    return episodes.groupby(["policy", "task"], as_index=False).agg(trials=("success", "size"),
                                                                   successes=("success", "sum"))


def from_csv(path: str) -> pd.DataFrame:
    """The CSV's policy, task, trials and successes, refused when a column is missing or a count is impossible."""
    table = pd.read_csv(path)
    missing = {"policy", "task", "trials", "successes"} - set(table.columns)
    if missing:
        raise DataError(f"{path}: missing column(s) {sorted(missing)}")
    bad = table[(table["trials"] <= 0) | (table["successes"] < 0) | (table["successes"] > table["trials"])]
    if len(bad):
        raise DataError(f"{path}: impossible counts for {bad[['policy', 'task']].values.tolist()}")
    return table[["policy", "task", "trials", "successes"]]


def reference_table(csv: str | None = None, rollout_dirs: list[str] | None = None) -> pd.DataFrame:
    """The reference counts from ``csv`` when given, else from ``rollout_dirs``, with ``success_rate``."""
    table = from_csv(csv) if csv else from_rollouts(rollout_dirs)
    table["success_rate"] = table["successes"] / table["trials"]
    return table.sort_values(["policy", "task"]).reset_index(drop=True)
