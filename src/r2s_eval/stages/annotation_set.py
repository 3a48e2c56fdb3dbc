"""Stage: the blinded A/B annotation set drawn from the compared pairs.

Balanced over the outcome categories, spread over tasks, A/B shown in a fresh seeded order, the
videos copied under opaque tokens; a category short of pairs is taken whole and its shortfall
recorded (``summary.json``). Serve it with ``python -m r2s_eval.annotate serve``.
"""

from __future__ import annotations

import logging

import pandas as pd

from r2s_eval.annotate import draw_annotation_set, write_annotation_set
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes

READS = ("annotate.n_pairs", "seed")  # config paths the --cfg slice holds (see _reads.py)

log = logging.getLogger("r2s_eval.annotation_set")


def main(args) -> None:
    episodes = load_episodes(args.rollouts)
    items, summary = draw_annotation_set(pd.read_parquet(args.pairs), episodes,
                                         n_pairs=int(args.cfg["annotate.n_pairs"]), seed=int(args.cfg["seed"]))
    write_annotation_set(items, summary, episodes, set_path=args.out, videos_dir=args.videos, summary_path=args.summary)
    for category, c in summary["categories"].items():
        level = logging.WARNING if c["shortfall"] else logging.INFO
        log.log(level, "%s: %d of %d pairs (the compared pairs hold %d)", category, c["drawn"], c["target"],
                c["available"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--pairs", required=True, help="the compared pairs (compare_pairs)")
    p.add_argument("--rollouts", nargs="+", required=True, help="sim rollout folders, one per policy")
    p.add_argument("--out", required=True, help="the set's key table (parquet)")
    p.add_argument("--videos", required=True, help="folder for the videos under their tokens")
    p.add_argument("--summary", required=True, help="JSON: per category target, drawn, shortfall")
    _cli.run(main, p)
