"""Stage: one judge's win-rate matrix (row policy's share of wins against the column policy)."""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import save_figure, win_rate_figure, win_rate_matrix
from r2s_eval.stages import _cli

READS = ("report.win_rate_matrix",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.win_rate_matrix"]
    rates = win_rate_matrix(pd.read_parquet(args.verdicts))
    save_figure(win_rate_figure(rates, args.judge, opts), args.pdf, args.png, dpi=opts["dpi"])
    print(rates.round(3).to_string())


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--judge", required=True)
    p.add_argument("--verdicts", required=True)
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
