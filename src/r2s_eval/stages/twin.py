"""Stage: sample the reality twin's perturbed physics, cameras and lighting, and its reality effects (seeded)."""

from __future__ import annotations

from r2s_eval.sim import world_robot
from r2s_eval.stages import _cli
from r2s_eval.twin import twin_world
from r2s_eval.utils.io import write_json

READS = ("real.twin", "world.objects", "world.robot", "world.rig")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    # All the world's objects, so the twin (and its seed) does not depend on which tasks run.
    # The robot's arms and rig cameras decide which joints and cameras are perturbed.
    robot = world_robot({"robot": args.cfg["world.robot"], "rig": args.cfg["world.rig"]})
    write_json(args.out, twin_world(args.cfg["real.twin"], args.cfg["world.objects"], robot), provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
