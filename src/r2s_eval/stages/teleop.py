"""Stage: the scripted operator records the teleop dataset in the reality twin.

Operators keep the demonstrations that succeed (as a lab discards botched takes); every
attempt is logged, a failed one with the operator's phase and reason (in the truth file's
metadata, counted per task in the world report). The twin's true initial poses go to a separate
file used only to score the initial-pose estimates (``r2s_eval.twin.record``). The world's
physical check (``r2s_eval.sim.world_check``) runs first: a world that fails it stops the stage
before it records, one line per problem.
"""

from __future__ import annotations

from r2s_eval.sim import load_world_params
from r2s_eval.sim.grasping import grasp_settings
from r2s_eval.sim.world_check import check_world
from r2s_eval.stages import _cli
from r2s_eval.twin.reality import load_reality_effects
from r2s_eval.twin.record import record_teleop
from r2s_eval.utils.io import write_parquet

READS = ("teleop", "tasks", "suite", "world", "seed")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg, teleop = args.cfg, args.cfg["teleop"]  # the group whole: record_teleop reads all of it
    # Fingers flung past their limits or a grasp that drops its object would record only failures.
    check_world(cfg["world"], cfg["tasks"], grasp_settings(teleop["operator"]))  # as the operator grasps
    truth, attempts = record_teleop(args.dataset, load_world_params(args.twin), teleop=teleop, world=cfg["world"],
                                    tasks=cfg["tasks"], suite=cfg["suite"], seed=cfg["seed"],
                                    reality=load_reality_effects(args.twin))
    write_parquet(args.truth, truth, metadata={"stage": "teleop", "attempts": attempts})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--twin", required=True)
    p.add_argument("--dataset", required=True)
    p.add_argument("--truth", required=True)
    _cli.run(main, p)
