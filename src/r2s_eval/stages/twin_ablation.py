"""Stage: the twin with one perturbation family's gap to the calibrated sim taken away.

That family's parameters take the calibrated sim's values (``r2s_eval.twin.perturb.without_family``);
``all`` gives the calibrated sim itself. pi^S rolled out there measures what the family costs.
"""

from __future__ import annotations

import dataclasses

from r2s_eval.sim import load_world_params
from r2s_eval.stages import _cli
from r2s_eval.twin.perturb import without_family
from r2s_eval.utils.io import write_json

READS = ()  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("family",)  # the family the rule takes away


def main(args) -> None:
    family = args.cfg["family"]
    params = without_family(load_world_params(args.twin), load_world_params(args.sim), family)
    write_json(args.out, {"params": dataclasses.asdict(params), "without": family}, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--twin", required=True, help="the twin's world parameters")
    p.add_argument("--sim", required=True, help="the calibrated sim's world parameters")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
