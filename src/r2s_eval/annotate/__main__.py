"""People compare rollout pairs: ``python -m r2s_eval.annotate serve | status | export``.

  serve   the annotation page for an annotation set (built by ``snakemake results/annotate/set.parquet``)
  status  how far each annotator is
  export  the answers as the CSV ``report.judge_audit.human_annotations`` names
"""

from __future__ import annotations

import argparse
import sys

from r2s_eval.annotate.app import load_set, serve
from r2s_eval.annotate.answers import AnswerStore
from r2s_eval.errors import R2SError
from r2s_eval.utils.io import atomic_path

SET_DIR = "results/annotate"
DB = "results/annotate/answers.sqlite"
CSV = "results/annotate/annotations.csv"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m r2s_eval.annotate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    for name, text in (("serve", "serve the annotation page"), ("status", "answers per annotator"),
                       ("export", "write the answers as a CSV")):
        cmd = sub.add_parser(name, help=text)
        cmd.add_argument("--set", default=SET_DIR, help=f"annotation set folder (default {SET_DIR})")
        cmd.add_argument("--db", default=DB, help=f"SQLite file of the answers (default {DB})")
    sub.choices["serve"].add_argument("--host", default="127.0.0.1",
                                      help="address to listen on (default 127.0.0.1: this machine only)")
    sub.choices["serve"].add_argument("--port", type=int, default=8765)
    sub.choices["export"].add_argument("--out", default=CSV, help=f"CSV to write (default {CSV})")
    args = p.parse_args(argv)
    try:
        if args.command == "serve":
            serve(args.set, args.db, host=args.host, port=args.port)
            return 0
        store = AnswerStore(args.db, load_set(args.set))
        answers = store.export()
        if args.command == "status":
            total = len(store.items)
            counts = answers.groupby("annotator").size() if len(answers) else {}
            for annotator, n in dict(counts).items():
                print(f"{annotator:<24}{n:>5} / {total}")
            print(f"{len(counts)} annotators, {len(answers)} answers")
        else:
            with atomic_path(args.out) as tmp:
                answers.to_csv(tmp, index=False)
            print(f"{len(answers)} answers of {answers['annotator'].nunique()} annotators -> {args.out}")
        store.close()
    except R2SError as err:
        print(f"annotate {args.command} failed: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
