"""Stage: the LIBERO table (one row per judge: rho, r, MMRV, BT CI width, human agreement,
order-swap consistency; then LIBERO's own success per policy and suite) and the printed ranking.

The judges' rows are the real-to-sim table's (same options, `report.realsim_table`): the method
validates both settings the same way, against LIBERO's success rate here.
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.libero import suite_of
from r2s_eval.report import libero_success_table, ranking_text, realsim_table, reference_interval
from r2s_eval.stages import _cli
from r2s_eval.stats import reference_rates
from r2s_eval.utils.io import read_json, read_parquet_metadata, write_text

READS = ("report.realsim_table", "report.judge_audit.planted_order")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.realsim_table"]
    validations = _cli.by_judge(args.validation, read_json)
    audits = _cli.by_judge(args.audits, read_json)
    fits = _cli.by_judge(args.fits, pd.read_parquet)
    table = pd.read_parquet(args.reference)
    judges = realsim_table(validations, audits, decimals=int(opts["decimals"]), metrics_at=opts["metrics_at"])
    success = libero_success_table(table, suite_of, decimals=1)
    write_text(args.table, judges + "\n" + success, comment="%")
    adaptive = {judge: meta.get("adaptive") for judge, meta in _cli.by_judge(args.fits, read_parquet_metadata).items()}
    text = ranking_text(fits, reference_rates(table).to_dict(), reference_interval(validations),
                        planted_order=args.cfg["report.judge_audit.planted_order"], reference_name="LIBERO success",
                        adaptive=adaptive)
    write_text(args.ranking, text)
    print(text)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    _cli.add_validation_table_inputs(p)
    _cli.run(main, p)
