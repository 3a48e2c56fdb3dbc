"""Stage: draw the seeded initial configurations shared by every policy and both arms."""

from __future__ import annotations

from r2s_eval.rollout import sample_inits
from r2s_eval.stages import _cli
from r2s_eval.sim.build import configured_task
from r2s_eval.utils.io import write_parquet

READS = ("tasks", "suite", "world.objects", "world.tasks", "rollout.inits_per_task", "seed")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    world = {"objects": cfg["world.objects"], "tasks": cfg["world.tasks"]}
    inits = sample_inits(
        [configured_task(t, world, cfg["suite"]) for t in cfg["tasks"]], int(cfg["rollout.inits_per_task"]), int(cfg["seed"])
    )
    write_parquet(args.out, inits, metadata={"stage": "rollout_inits", "seed": cfg["seed"]})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
