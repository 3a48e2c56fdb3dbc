"""Stage: the judge answers A or B for every sampled pair (cached by content).

Two-step judges compare the descriptions; one-step judges watch both videos. Replacements for
excluded comparisons come from the seeded continuation of the pair sequences
(``sample_reserve``), drawn from the same rollouts with the same seed as the pairs themselves.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from r2s_eval.compare.reserve import reserve_for
from r2s_eval.judge import judge_pairs
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.stages import _cli
from r2s_eval.world_judging import world_judge, write_verdicts

READS = ("seed", "world.objects", "world.tasks", "world.robot")  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("judge", "name")  # keys the rule adds for this job


def main(args) -> None:
    cfg = args.cfg
    # Transport keys (server address, timeouts, concurrency) come apart: they never rerun judging.
    judge = world_judge(cfg["judge"], json.loads(args.transport), objects=cfg["world.objects"],
                        tasks=cfg["world.tasks"], robot=cfg["world.robot"])
    pairs = pd.read_parquet(args.pairs)
    episodes = load_episodes(args.rollouts)
    out = Path(args.out)
    verdicts = judge_pairs(
        pairs, pd.read_parquet(args.descriptions) if args.descriptions else None, judge, args.cache,
        stats_path=out.with_name("compare_stats.json"), episodes_df=episodes, episodes_dir=Path("."),
        reserve_df=reserve_for(pairs, args.pairs, episodes, int(cfg["seed"]), int(judge.stage_cfg["reserve"])),
    )
    write_verdicts(out, verdicts, cfg["name"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--pairs", required=True)
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--descriptions", default=None, help="descriptions table (two-step judges)")
    p.add_argument("--cache", required=True)
    p.add_argument("--transport", default="{}", help="JSON: the judge's transport keys")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
