"""Stage: real-world reference success rates per policy and task.

From closed-loop rollouts on the real side (the twin, or a robot logged the same way), or
from a CSV of hardware trials with columns policy, task, trials, successes.

The table stays per task: a policy's reference performance is the mean of its per-task
rates (every task weighs the same), and its bootstrap interval resamples the trials within
each task, so both are computed from these counts where they are used
(``r2s_eval.stats.reference_rates``; the interval in the validate stage, with the
statistics config and seed). Nothing here depends on that config, so changing it does not
rerun the reference.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_parquet
from r2s_eval.errors import DataError

READS = ()  # config paths the --cfg slice holds (see _reads.py)


def from_rollouts(rollout_dirs: list[str]) -> pd.DataFrame:
    frames = [pd.read_parquet(Path(d) / "episodes.parquet") for d in rollout_dirs]
    episodes = pd.concat(frames, ignore_index=True)
    table = episodes.groupby(["policy", "task"], as_index=False).agg(
        trials=("success", "size"), successes=("success", "sum")
    )
    return table


def from_csv(path: str) -> pd.DataFrame:
    table = pd.read_csv(path)
    missing = {"policy", "task", "trials", "successes"} - set(table.columns)
    if missing:
        raise DataError(f"{path}: missing column(s) {sorted(missing)}")
    bad = table[(table["trials"] <= 0) | (table["successes"] < 0) | (table["successes"] > table["trials"])]
    if len(bad):
        raise DataError(f"{path}: impossible counts for {bad[['policy', 'task']].values.tolist()}")
    return table[["policy", "task", "trials", "successes"]]


def main(args) -> None:
    table = from_csv(args.csv) if args.csv else from_rollouts(args.rollouts)
    table["success_rate"] = table["successes"] / table["trials"]
    write_parquet(args.out, table.sort_values(["policy", "task"]).reset_index(drop=True))


if __name__ == "__main__":
    p = _cli.parser(__doc__, cfg=False)
    p.add_argument("--rollouts", nargs="*", default=[])
    p.add_argument("--csv")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
