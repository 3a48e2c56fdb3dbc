"""Stage: the judge answers A or B for every sampled pair (cached by content)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from r2s_eval.judge import judge_pairs, make_judge
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_parquet


def main(args) -> None:
    judge = make_judge(args.cfg["judge"])
    pairs = pd.read_parquet(args.pairs)
    descriptions = pd.read_parquet(args.descriptions)
    out = Path(args.out)
    verdicts = judge_pairs(pairs, descriptions, judge, args.cache, stats_path=out.with_name("compare_stats.json"))
    write_parquet(out, verdicts, metadata={"stage": "judge_pairs", "judge": args.cfg["name"]})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--pairs", required=True)
    p.add_argument("--descriptions", required=True)
    p.add_argument("--cache", required=True)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
