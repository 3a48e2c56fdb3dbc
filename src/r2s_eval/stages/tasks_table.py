"""Stage: the tasks table (per task: real and sim trajectories, replay success %)."""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import task_summary, tasks_table
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_text

READS = ("report.tasks_table",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.tasks_table"]
    summary = task_summary(pd.read_parquet(args.index), pd.read_parquet(args.replay_log))
    write_text(args.out, tasks_table(summary, decimals=int(opts["decimals"])), comment="%")
    print(summary.to_string(index=False))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--index", required=True, help="ingest's episode index")
    p.add_argument("--replay-log", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
