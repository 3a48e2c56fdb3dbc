"""Stage: the judges' resolution card (reports/judge_resolution_table.tex) and figure
(reports/judge_resolution.{pdf,png}) from every judge's results/resolution/<judge>.json."""

from __future__ import annotations

from r2s_eval.report import resolution_figure, resolution_table, save_figure
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_json, write_text

READS = ("report.judge_resolution",)  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    opts = args.cfg["report.judge_resolution"]
    cards = _cli.by_judge(args.cards, read_json)
    write_text(args.table, resolution_table(cards, decimals=int(opts["decimals"])), comment="%")
    save_figure(resolution_figure(cards, opts), args.pdf, args.png, dpi=int(opts["dpi"]))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--cards", nargs="+", required=True, help="the resolution JSON per judge (results/resolution/<judge>.json)")
    p.add_argument("--table", required=True)
    p.add_argument("--pdf", required=True)
    p.add_argument("--png", required=True)
    _cli.run(main, p)
