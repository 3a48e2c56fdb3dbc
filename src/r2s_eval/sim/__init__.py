"""Simulated dual-arm tabletop world.

Modules: ``robot`` (a world's robot and camera rig, read from its config), ``world`` (scene
assembly from them), ``objects`` (parametric
objects), ``cameras`` (intrinsics/extrinsics/projection), ``tasks`` (registry,
success and progress), ``env`` (``TabletopEnv``), ``params`` (``WorldParams``, the
physics and rendering knobs of one world), ``sensor`` (what its camera records: the world's lens,
its pixel noise), ``build`` (environments from the config slices). The reality twin and the scripted operator live in ``r2s_eval.twin``, which
builds on this package (never the reverse).
Rendering is headless: ``MUJOCO_GL`` defaults to ``egl`` unless already set.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from r2s_eval.sim.env import TabletopEnv  # noqa: E402
from r2s_eval.sim.params import WorldParams, load_world_params, world_params_from_record  # noqa: E402
from r2s_eval.sim.robot import Robot, world_robot  # noqa: E402
from r2s_eval.sim.tasks import Task, get_task, world_config  # noqa: E402

__all__ = [
    "Robot",
    "Task",
    "TabletopEnv",
    "WorldParams",
    "get_task",
    "load_world_params",
    "world_config",
    "world_params_from_record",
    "world_robot",
]
