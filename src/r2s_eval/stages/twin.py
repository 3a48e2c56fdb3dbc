"""Stage: sample the reality twin's perturbed physics, cameras and lighting (seeded)."""

from __future__ import annotations

import dataclasses

import numpy as np

from r2s_eval.sim import TwinMagnitudes, get_task, sample_twin_params
from r2s_eval.sim.twin import ALL_OBJECT_NAMES, CAMERA_NAMES
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json


def main(args) -> None:
    twin = args.cfg["real.twin"]
    magnitudes = TwinMagnitudes(**(twin.get("magnitudes") or {}))
    # All objects of the suite, so the twin (and its seed) does not depend on which tasks run.
    objects = sorted(set(ALL_OBJECT_NAMES) | {o.name for task in args.cfg.get("tasks", []) or [] for o in get_task(task).objects})
    params = sample_twin_params(np.random.default_rng(int(twin["seed"])), magnitudes, tuple(objects), CAMERA_NAMES)
    write_json(args.out, {"magnitudes": dataclasses.asdict(magnitudes), "params": dataclasses.asdict(params)})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--out", required=True)
    _cli.run(main, p)
