"""Stage: the twin with one of its reality effects alone (``fidelity.ablation.alone``).

Its world parameters stay the twin's (the errors the calibration finds); of its reality effects
(``r2s_eval.twin.reality``) only the named family's is on (``r2s_eval.twin.perturb.reality_alone``);
``none``: every one off, the reference each effect is measured against. Writes
``{"params", "reality", "alone"}``, so the real arm's rollouts there run in the twin's
environment; pi^S rolled out there measures what the effect costs on its own.
"""

from __future__ import annotations

import dataclasses

from r2s_eval.errors import DataError
from r2s_eval.sim import load_world_params
from r2s_eval.stages import _cli
from r2s_eval.twin.perturb import reality_alone
from r2s_eval.twin.reality import load_reality_effects, reality_record
from r2s_eval.utils.io import write_json

READS = ()  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("effect",)  # the family left on


def main(args) -> None:
    effect = args.cfg["effect"]
    reality = load_reality_effects(args.twin)
    if reality is None:
        raise DataError(f"{args.twin}: this twin has no reality effects to take one alone "
                        "(fidelity.ablation.alone needs a twin with them, e.g. real=twin_unmodelled)")
    write_json(args.out, {"params": dataclasses.asdict(load_world_params(args.twin)),
                          **reality_record(reality_alone(reality, effect)), "alone": effect}, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--twin", required=True, help="the twin's world parameters and reality effects")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
