"""Stage: the judge describes sim rollouts (the workflow: one policy's), each once (cached by content)."""

from __future__ import annotations

import json
from pathlib import Path

from r2s_eval.judge import describe_rollouts
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.stages import _cli
from r2s_eval.world_judging import world_judge, write_descriptions

READS = ("world.objects", "world.tasks", "world.robot")  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("judge", "name")  # keys the rule adds for this job


def main(args) -> None:
    cfg = args.cfg
    judge = world_judge(cfg["judge"], json.loads(args.transport), objects=cfg["world.objects"],
                        tasks=cfg["world.tasks"], robot=cfg["world.robot"])
    out = Path(args.out)
    stats = Path(args.stats) if args.stats else out.with_name("describe_stats.json")
    descriptions = describe_rollouts(load_episodes(args.rollouts), Path("."), judge, args.cache, stats_path=stats)
    write_descriptions(out, descriptions, cfg["name"])


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--cache", required=True)
    p.add_argument("--transport", default="{}", help="JSON: the judge's transport keys")
    p.add_argument("--out", required=True)
    p.add_argument("--stats", default=None, help="the judge's costs as JSON (default: describe_stats.json beside --out)")
    _cli.run(main, p)
