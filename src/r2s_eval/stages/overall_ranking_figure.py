"""Stage: the judge-averaged preference score beside the reference performance (the mean of
the per-task success rates, with validate's interval as error bars when given)."""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import judge_averaged_scores, ranking_figure, reference_interval, save_figure
from r2s_eval.stages import _cli
from r2s_eval.stats import reference_rates
from r2s_eval.utils.io import read_json

READS = ("report.overall_ranking",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.overall_ranking"]
    averaged = judge_averaged_scores(_cli.by_judge(args.fits, pd.read_parquet))
    reference = reference_rates(pd.read_parquet(args.reference)).to_dict()
    reference_ci = reference_interval(_cli.by_judge(args.validation, read_json))
    figure = ranking_figure(averaged, reference, opts, reference_ci, reference_name=args.reference_name)
    save_figure(figure, args.pdf, args.png, dpi=opts["dpi"])
    print(averaged.round(2).to_string())


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fits", nargs="+", required=True, help="fit table per judge (results/fit/<judge>.parquet)")
    p.add_argument("--reference", required=True)
    p.add_argument("--validation", nargs="*", default=[], help="validate's JSON per judge (the reference's interval)")
    p.add_argument("--reference-name", default="real success", help="what the reference is (its axis label)")
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
