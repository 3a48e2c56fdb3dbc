"""Stage: a sim the fidelity crossing also runs the checkpoints in (``fidelity.sims``).

``nominal``: the world as its files state it, nothing calibrated; ``without_answers``: the
calibration without its answers to what the world files cannot state (the lens, the background
plates, the commands' latency, the key light's shadows: ``r2s_eval.sim.params.ANSWERS``), the
calibration as it was before
those answers; ``without_<answer>``: the calibration without that one. Writes ``{"params", "sim"}``
(no reality effects: a sim).
"""

from __future__ import annotations

import dataclasses

from r2s_eval.sim import load_world_params
from r2s_eval.sim.params import sim_variant
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json

READS = ()  # config paths the --cfg slice holds (see _reads.py)
PROVIDED = ("sim",)  # the variant the rule makes


def main(args) -> None:
    name = args.cfg["sim"]
    params = sim_variant(load_world_params(args.calibrated), name)
    write_json(args.out, {"params": dataclasses.asdict(params), "sim": name}, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--calibrated", required=True, help="the calibrated sim's world parameters")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
