"""Stage: BT scores with bootstrap bands over the checkpoints, one panel per judge."""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import convergence_figure, save_figure
from r2s_eval.stages import _cli

READS = ("report.bt_convergence",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.bt_convergence"]
    fits = _cli.by_judge(args.fits, pd.read_parquet)
    save_figure(convergence_figure(fits, opts), args.pdf, args.png, dpi=opts["dpi"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fits", nargs="+", required=True, help="fit table per judge (results/fit/<judge>.parquet)")
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
