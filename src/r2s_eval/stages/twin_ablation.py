"""Stage: the twin with one perturbation family's gap to the calibrated sim taken away.

That family's world parameters take the calibrated sim's values and its reality effects are set
off (``r2s_eval.twin.perturb.without_family``, ``reality_without_family``): the twin without its
lens records through the lens the calibration fitted, the twin without its latency answers as
late as the calibration estimated; ``all`` gives the calibrated sim itself. Writes
``{"params", "reality", "without"}`` (``reality`` where the twin has one), so the real arm's
rollouts there run in the twin's environment; pi^S rolled out there measures what the family
costs.
"""

from __future__ import annotations

import dataclasses

from r2s_eval.sim import load_world_params
from r2s_eval.stages import _cli
from r2s_eval.twin.perturb import reality_without_family, without_family
from r2s_eval.twin.reality import load_reality_effects, reality_record
from r2s_eval.utils.io import write_json

READS = ()  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("family",)  # the family the rule takes away


def main(args) -> None:
    family = args.cfg["family"]
    params = without_family(load_world_params(args.twin), load_world_params(args.sim), family)
    reality = load_reality_effects(args.twin)
    reality = None if reality is None else reality_without_family(reality, family)
    write_json(args.out, {"params": dataclasses.asdict(params), **reality_record(reality), "without": family},
               provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--twin", required=True, help="the twin's world parameters and reality effects")
    p.add_argument("--sim", required=True, help="the calibrated sim's world parameters")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
