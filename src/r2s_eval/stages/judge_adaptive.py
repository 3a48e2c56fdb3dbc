"""Stage: the judge answers A or B, block by block, for the policy pairs whose order is still open
(``compare.allocation: adaptive``; see ``r2s_eval.judge.adaptive``).

Two-step judges describe each rollout when a chosen comparison first needs it; the descriptions
made go to ``--descriptions-out`` and their cost to ``describe_stats.json`` beside it.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from r2s_eval.errors import DataError
from r2s_eval.judge import make_judge
from r2s_eval.judge.adaptive import judge_adaptively
from r2s_eval.sim.robot import world_robot
from r2s_eval.sim.tasks import world_tasks
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import read_parquet_metadata, write_parquet
from r2s_eval.compare import checkpoint_sizes

READS = ("compare", "world.objects", "world.tasks", "world.robot")  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("judge", "name")  # keys the rule adds for this job


def main(args) -> None:
    cfg = args.cfg
    judge = make_judge({**cfg["judge"], **json.loads(args.transport)})
    judge.know_tasks(world_tasks({"objects": cfg["world.objects"], "tasks": cfg["world.tasks"]}))
    judge.know_robot(world_robot({"robot": cfg["world.robot"], "rig": {}}))  # its units, not its cameras
    if read_parquet_metadata(args.pairs).get("allocation") != "adaptive":
        raise DataError(f"{args.pairs} holds no adaptive unit order; rerun compare_pairs with compare.allocation: adaptive")
    units = pd.read_parquet(args.pairs)
    episodes = load_episodes(args.rollouts)
    compare = cfg["compare"]
    checkpoints = checkpoint_sizes(compare["checkpoints"])
    budget = int(compare["budget"] or max(checkpoints))
    out = Path(args.out)
    describe_stats = Path(args.descriptions_out).with_name("describe_stats.json") if args.descriptions_out else None
    verdicts, descriptions = judge_adaptively(
        units, judge, args.cache, alpha=float(compare["alpha"]), budget_per_pair=budget, checkpoints=checkpoints,
        episodes_df=episodes, episodes_dir=Path("."), stats_path=out.with_name("compare_stats.json"),
        describe_stats_path=describe_stats,
    )
    stats = {k: v for k, v in verdicts.attrs["stats"].items() if k != "exclusions"}
    write_parquet(out, verdicts, metadata={"stage": "judge_pairs", "judge": cfg["name"], "stats": stats})
    if args.descriptions_out:
        if descriptions is None:
            raise DataError(f"judge {cfg['name']!r} compares videos (one_step): it makes no descriptions")
        write_parquet(args.descriptions_out, descriptions,
                      metadata={"stage": "describe", "judge": cfg["name"], "stats": descriptions.attrs["stats"]})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--pairs", required=True, help="the unit order (compare_pairs, allocation adaptive)")
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--cache", required=True)
    p.add_argument("--transport", default="{}", help="JSON: the judge's transport keys")
    p.add_argument("--out", required=True)
    p.add_argument("--descriptions-out", default=None, help="two-step judges: the descriptions made on the way")
    _cli.run(main, p)
