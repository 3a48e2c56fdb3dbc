"""Stage: the judge answers A or B, block by block, for the policy pairs whose order is still open
(``compare.allocation: adaptive``; see ``r2s_eval.judge.adaptive``).

Two-step judges describe each rollout when a chosen comparison first needs it; the descriptions
made go to ``--descriptions-out`` and their cost to ``describe_stats.json`` beside it.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from r2s_eval.compare import checkpoint_sizes
from r2s_eval.errors import DataError
from r2s_eval.judge.adaptive import judge_adaptively
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.stages import _cli
from r2s_eval.utils.io import read_parquet_metadata
from r2s_eval.world_judging import world_judge, write_descriptions, write_verdicts

READS = ("compare.checkpoints", "compare.budget", "compare.alpha", "world.objects", "world.tasks",
         "world.robot")  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("judge", "name")  # keys the rule adds for this job


def main(args) -> None:
    cfg = args.cfg
    judge = world_judge(cfg["judge"], json.loads(args.transport), objects=cfg["world.objects"],
                        tasks=cfg["world.tasks"], robot=cfg["world.robot"])
    if read_parquet_metadata(args.pairs).get("allocation") != "adaptive":
        raise DataError(f"{args.pairs} holds no adaptive unit order; rerun compare_pairs with compare.allocation: adaptive")
    checkpoints = checkpoint_sizes(cfg["compare.checkpoints"])
    out = Path(args.out)
    describe_stats = Path(args.descriptions_out).with_name("describe_stats.json") if args.descriptions_out else None
    verdicts, descriptions = judge_adaptively(
        pd.read_parquet(args.pairs), judge, args.cache, alpha=float(cfg["compare.alpha"]),
        budget_per_pair=int(cfg["compare.budget"] or max(checkpoints)), checkpoints=checkpoints,
        episodes_df=load_episodes(args.rollouts), episodes_dir=Path("."), stats_path=out.with_name("compare_stats.json"),
        describe_stats_path=describe_stats,
    )
    write_verdicts(out, verdicts, cfg["name"])
    if args.descriptions_out:
        if descriptions is None:
            raise DataError(f"judge {cfg['name']!r} compares videos (one_step): it makes no descriptions")
        write_descriptions(args.descriptions_out, descriptions, cfg["name"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--pairs", required=True, help="the unit order (compare_pairs, allocation adaptive)")
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--cache", required=True)
    p.add_argument("--transport", default="{}", help="JSON: the judge's transport keys")
    p.add_argument("--out", required=True)
    p.add_argument("--descriptions-out", default=None, help="two-step judges: the descriptions made on the way")
    _cli.run(main, p)
