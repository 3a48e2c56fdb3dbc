"""Stage: the real-to-sim validation table (one row per judge) and the printed ranking.

Both say which bootstrap their intervals come from; the ranking shows the reference as the
mean of the per-task success rates, with the interval validate computed for it.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.report import ranking_text, realsim_table, reference_interval
from r2s_eval.stages import _cli
from r2s_eval.stats import reference_rates
from r2s_eval.utils.io import read_json, read_parquet_metadata, write_text

READS = ("report.realsim_table", "report.judge_audit.planted_order")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.realsim_table"]
    validations = _cli.by_judge(args.validation, read_json)
    audits = _cli.by_judge(args.audits, read_json)
    fits = _cli.by_judge(args.fits, pd.read_parquet)
    reference = reference_rates(pd.read_parquet(args.reference))
    table = realsim_table(validations, audits, decimals=int(opts["decimals"]), metrics_at=opts["metrics_at"])
    write_text(args.table, table, comment="%")
    adaptive = {judge: meta.get("adaptive") for judge, meta in _cli.by_judge(args.fits, read_parquet_metadata).items()}
    text = ranking_text(fits, reference.to_dict(), reference_interval(validations),
                        planted_order=args.cfg["report.judge_audit.planted_order"], adaptive=adaptive)
    write_text(args.ranking, text)  # printed at the end of a run: kept free of metadata lines
    print(text)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    _cli.add_validation_table_inputs(p)
    _cli.run(main, p)
