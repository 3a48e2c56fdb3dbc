"""Simulated dual-arm tabletop world.

Modules: ``world`` (scene assembly from ``assets/``), ``objects`` (parametric
objects), ``cameras`` (intrinsics/extrinsics/projection), ``tasks`` (registry,
success and progress), ``env`` (``TabletopEnv``), ``params`` (``WorldParams``, the
physics and rendering knobs of one world), ``build`` (environments from the config
slices). The reality twin and the scripted operator live in ``r2s_eval.twin``, which
builds on this package (never the reverse).
Rendering is headless: ``MUJOCO_GL`` defaults to ``egl`` unless already set.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from r2s_eval.sim.env import ACTION_DIM, TabletopEnv  # noqa: E402
from r2s_eval.sim.params import CAMERA_NAMES, WorldParams, load_world_params  # noqa: E402
from r2s_eval.sim.tasks import TASKS, Task, get_task  # noqa: E402

__all__ = [
    "ACTION_DIM",
    "CAMERA_NAMES",
    "TASKS",
    "Task",
    "TabletopEnv",
    "WorldParams",
    "get_task",
    "load_world_params",
]
