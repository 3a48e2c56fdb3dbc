"""Stage: the judge describes sim rollouts (the workflow: one policy's), each once (cached by content)."""

from __future__ import annotations

import json
from pathlib import Path

from r2s_eval.judge import describe_rollouts, make_judge
from r2s_eval.sim.robot import world_robot
from r2s_eval.sim.tasks import world_tasks
from r2s_eval.stages import _cli
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import write_parquet

READS = ("world.objects", "world.tasks", "world.robot")  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("judge", "name")  # keys the rule adds for this job


def main(args) -> None:
    # Transport keys (server address, timeouts, concurrency) come apart: they never rerun judging.
    judge = make_judge({**args.cfg["judge"], **json.loads(args.transport)})
    judge.know_tasks(world_tasks({"objects": args.cfg["world.objects"], "tasks": args.cfg["world.tasks"]}))
    judge.know_robot(world_robot({"robot": args.cfg["world.robot"], "rig": {}}))  # its units, not its cameras
    episodes = load_episodes(args.rollouts)
    out = Path(args.out)
    stats = Path(args.stats) if args.stats else out.with_name("describe_stats.json")
    descriptions = describe_rollouts(episodes, Path("."), judge, args.cache, stats_path=stats)
    write_parquet(out, descriptions, metadata={"stage": "describe", "judge": args.cfg["name"],
                                               "stats": descriptions.attrs["stats"]})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--rollouts", nargs="+", required=True)
    p.add_argument("--cache", required=True)
    p.add_argument("--transport", default="{}", help="JSON: the judge's transport keys")
    p.add_argument("--out", required=True)
    p.add_argument("--stats", default=None, help="the judge's costs as JSON (default: describe_stats.json beside --out)")
    _cli.run(main, p)
