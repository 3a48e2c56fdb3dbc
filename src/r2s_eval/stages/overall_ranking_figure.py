"""Stage: the judge-averaged preference score beside the reference success rate."""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import judge_averaged_scores, ranking_figure, save_figure
from r2s_eval.stages import _cli
from r2s_eval.stages.validate import reference_rates


def main(args) -> None:
    opts = args.cfg["report.overall_ranking"]
    averaged = judge_averaged_scores(_cli.by_judge(args.fits, pd.read_parquet))
    reference = reference_rates(pd.read_parquet(args.reference)).to_dict()
    save_figure(ranking_figure(averaged, reference, opts), args.pdf, args.png, dpi=opts["dpi"])
    print(averaged.round(2).to_string())


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fits", nargs="+", required=True, help="fit table per judge (results/fit/<judge>.parquet)")
    p.add_argument("--reference", required=True)
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
