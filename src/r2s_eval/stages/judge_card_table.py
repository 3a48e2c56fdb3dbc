"""Stage: the judge report card table (per judge, from results/audit/<judge>.json).

Outcome agreement on mixed-outcome pairs, planted-order agreement on same-outcome pairs,
position bias, order-swap consistency and the shuffled-label control, each with the
counts it rests on.
"""

from __future__ import annotations

from r2s_eval.report import judge_card_table
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_json, write_text

READS = ("report.judge_card_table",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.judge_card_table"]
    audits = _cli.by_judge(args.audits, read_json)
    write_text(args.out, judge_card_table(audits, decimals=int(opts["decimals"])), comment="%")


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--audits", nargs="+", required=True, help="judge audit JSON per judge (results/audit/<judge>.json)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
