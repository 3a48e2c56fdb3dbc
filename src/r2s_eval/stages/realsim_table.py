"""Stage: the real-to-sim validation table (one row per judge) and the printed ranking.

Both say which bootstrap their intervals come from; the ranking shows the reference as the
mean of the per-task success rates, with the interval validate computed for it.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import validation_report
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_json, read_parquet_metadata, write_text

READS = ("report.realsim_table", "report.judge_audit.planted_order")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.realsim_table"]
    table, text = validation_report(
        _cli.by_judge(args.validation, read_json), _cli.by_judge(args.audits, read_json),
        _cli.by_judge(args.fits, pd.read_parquet),
        {judge: meta.get("adaptive") for judge, meta in _cli.by_judge(args.fits, read_parquet_metadata).items()},
        pd.read_parquet(args.reference), decimals=int(opts["decimals"]), metrics_at=opts["metrics_at"],
        planted_order=args.cfg["report.judge_audit.planted_order"])
    write_text(args.table, table, comment="%")
    write_text(args.ranking, text)  # printed at the end of a run: kept free of metadata lines
    print(text)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    _cli.add_validation_table_inputs(p)
    _cli.run(main, p)
