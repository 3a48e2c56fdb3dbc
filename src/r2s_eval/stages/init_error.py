"""Stage: score the initial-pose estimates against the reality twin's recorded truth.

Besides the offset fit (which reads the truth of the held-out calibration episodes only),
this is the only reader of the truth file; nothing downstream consumes its output. The
calibration episodes are left out of the scores (``r2s_eval.calib.scoring``).
"""

from __future__ import annotations

import pandas as pd

from r2s_eval.calib.scoring import score_estimates
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json, write_parquet

READS = ()  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    errors, summary = score_estimates(pd.read_parquet(args.estimates), pd.read_parquet(args.truth))
    write_parquet(args.table, errors)
    write_json(args.summary, summary, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__, cfg=False)
    p.add_argument("--estimates", required=True)
    p.add_argument("--truth", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--summary", required=True)
    _cli.run(main, p)
