"""Stage: real vs sim success per task and policy, with totals and the real-sim gaps."""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import realsim_success_table, success_by_task
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import write_text

READS = ("report.realsim_success_table",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.realsim_success_table"]
    success = success_by_task(pd.read_parquet(args.reference), load_episodes(args.rollouts))
    write_text(args.out, realsim_success_table(success, decimals=int(opts["decimals"])), comment="%")
    print(success.to_string(index=False))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--reference", required=True, help="reference success table (the real side)")
    p.add_argument("--rollouts", nargs="+", required=True, help="sim rollout folders, one per policy")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
