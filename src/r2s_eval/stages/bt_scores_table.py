"""Stage: the BT scores table (per judge and policy, s at the last checkpoint with its CI).

The reference column is the mean of the per-task success rates; its interval comes from
validate's JSON when given.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import bt_scores_table, reference_interval
from r2s_eval.stages import _cli
from r2s_eval.stats import reference_rates
from r2s_eval.utils.io import read_json, write_text

READS = ("report.bt_scores_table",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.bt_scores_table"]
    fits = _cli.by_judge(args.fits, pd.read_parquet)
    reference = reference_rates(pd.read_parquet(args.reference)).to_dict()
    reference_ci = reference_interval(_cli.by_judge(args.validation, read_json))
    table = bt_scores_table(fits, reference, decimals=int(opts["decimals"]), show_ci=bool(opts["show_ci"]),
                            reference_ci=reference_ci, reference_name=args.reference_name)
    write_text(args.out, table, comment="%")


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--fits", nargs="+", required=True, help="fit table per judge (results/fit/<judge>.parquet)")
    p.add_argument("--reference", required=True)
    p.add_argument("--validation", nargs="*", default=[], help="validate's JSON per judge (the reference's interval)")
    p.add_argument("--reference-name", default="Real", help="what the reference is (its column's title)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
