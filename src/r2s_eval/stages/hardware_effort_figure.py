"""Stage: operator time of a real-world evaluation against r2s-eval's zero repeated hardware time.

The experiment's own scale (policies, tasks, trials per task) comes from the reference
table; the seconds per trial come from the config.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import hardware_effort_figure, save_figure
from r2s_eval.stages import _cli
from r2s_eval.errors import DataError

READS = ("report.hardware_effort",)  # config paths the --cfg slice holds (see _reads.py)


def experiment_scale(reference: pd.DataFrame) -> tuple[int, int, int]:
    """(policies, tasks, trials per task and policy, rounded mean) of a reference table."""
    if reference.empty:
        raise DataError("reference success table is empty")
    trials = round(reference.groupby(["policy", "task"])["trials"].sum().mean())
    return int(reference["policy"].nunique()), int(reference["task"].nunique()), trials


def main(args) -> None:
    opts = args.cfg["report.hardware_effort"]
    n_policies, n_tasks, n_trials = experiment_scale(pd.read_parquet(args.reference))
    fig = hardware_effort_figure(opts["seconds_per_trial"], n_policies, (n_tasks, n_trials), opts)
    save_figure(fig, args.pdf, args.png, dpi=opts["dpi"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--reference", required=True)
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
