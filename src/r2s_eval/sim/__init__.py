"""Simulated dual-arm tabletop world, its reality twin and a scripted teleoperator.

Modules: ``world`` (scene assembly from ``assets/``), ``objects`` (parametric
objects), ``cameras`` (intrinsics/extrinsics/projection), ``tasks`` (registry,
success and progress), ``env`` (``TabletopEnv``), ``twin`` (``WorldParams``,
perturbation sampling), ``teleop`` (scripted operator using mink IK).
Rendering is headless: ``MUJOCO_GL`` defaults to ``egl`` unless already set.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from r2s_eval.sim.env import ACTION_DIM, TabletopEnv  # noqa: E402
from r2s_eval.sim.tasks import TASKS, Task, get_task  # noqa: E402
from r2s_eval.sim.twin import CAMERA_NAMES, TwinMagnitudes, WorldParams, sample_twin_params  # noqa: E402

__all__ = [
    "ACTION_DIM",
    "CAMERA_NAMES",
    "TASKS",
    "Task",
    "TabletopEnv",
    "TwinMagnitudes",
    "WorldParams",
    "get_task",
    "sample_twin_params",
]
