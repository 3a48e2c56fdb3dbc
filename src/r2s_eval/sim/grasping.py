"""The top-down grasp, one owner for the scripted operator (``r2s_eval.twin.operator``), which makes
it in every episode, and the world check (``world_check``), which tries it before a run: the
hand's turn over the object, the height it closes at, the jaws' pre-shape, how fast the gripper
closes, how long it stays closed before the hand rises and how fast the hand rises.
``GraspSettings`` holds the settings; the operator's ``OperatorConfig`` extends it, so a
``teleop.operator`` entry that changes one changes it for both.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim.arm_ik import ArmIK, top_down_rotation
from r2s_eval.sim.objects import KINDS
from r2s_eval.sim.tasks import Task

STEP_S = 0.1  # the settings' step counts and per-step rates are for control steps of this length
HAND_TURNS_RAD = (0.0, np.pi / 2, np.pi, -np.pi / 2)  # about the reach: where the arm's natural hand yaw is sought
ON_SIDE_ABOVE_CENTRE_M = 0.004  # tcp above a lying cup's centre when closing across its middle (turn_upright)


@dataclass(frozen=True)
class GraspSettings:
    """The settings of the top-down grasp (the operator's ``OperatorConfig`` fields of these names)."""

    preshape_margin_m: float = 0.012  # jaw opening beyond a ball's/block's half width
    grasp_tcp_height_m: float = 0.05  # tcp above the table when closing on the cup
    gripper_rate_per_step: float = 0.35  # normalised gripper command change per step
    close_hold_steps: int = 3  # steps the closed gripper holds before the hand rises
    lift_speed_m_s: float = 0.15  # tcp speed lifting the object


def grasp_settings(operator: Mapping | None) -> GraspSettings:
    """The grasp settings an operator entry (``teleop.operator``: ``OperatorConfig`` fields) gives."""
    names = {f.name for f in dataclasses.fields(GraspSettings)}
    return GraspSettings(**{k: v for k, v in (operator or {}).items() if k in names})


def ticks(control_dt_s: float) -> int:
    """Control steps per step of the settings (``STEP_S``)."""
    return max(1, round(STEP_S / control_dt_s))


def natural_yaw(ik: ArmIK, centre: np.ndarray, reach_yaw_rad: float) -> float:
    """The yaw of the top-down hand the arm holds over ``centre`` with its joints nearest home:
    the reach direction, or a quarter or half turn from it (a wrist whose jaws close along the
    reach; a wrist that would otherwise turn to its limit)."""
    home = ik.robot.arms[ik.arm].home

    def cost(turn: float) -> float:
        q = ik.joints_for(centre, top_down_rotation(reach_yaw_rad + turn))
        return np.inf if q is None else float(np.linalg.norm(q - home))

    return reach_yaw_rad + min(HAND_TURNS_RAD, key=cost)


def closing_for_opening(jaw_opening_m: float, jaw_open_m: float) -> float:
    """Gripper command that opens each jaw ``jaw_opening_m`` from the grasp centre (of ``jaw_open_m`` fully open)."""
    return float(np.clip(1.0 - jaw_opening_m / jaw_open_m, 0.0, 1.0))


@dataclass(frozen=True)
class TopDownGrasp:
    """How the hand closes on an object from above: the gripper command it approaches with (0 open)
    and the tcp's height then, ``above_centre_m`` above the object's centre or, where that is None,
    ``above_table_m`` above the table."""

    preshape: float
    above_centre_m: float | None
    above_table_m: float | None = None

    def tcp_z_m(self, centre_z_m: float, table_z_m: float) -> float:
        if self.above_centre_m is not None:
            return centre_z_m + self.above_centre_m
        return table_z_m + self.above_table_m


def task_grasp(task: Task, name: str, dims: dict, jaw_open_m: float, settings: GraspSettings) -> TopDownGrasp:
    """How the task's plan has the hand take ``name``: across a lying cup's middle, jaws open
    (``turn_upright``), else as its kind is picked (``pick``: a cup round its wall near the table,
    jaws open; a ball or a block with the jaws pre-shaped just wider than it)."""
    if {"turn_upright": name} in task.plan:
        return TopDownGrasp(0.0, ON_SIDE_ABOVE_CENTRE_M)
    kind = task.object(name).kind_object
    grasp = kind.grasp(dims, task.placement(name))
    if grasp is None:
        pickable = [k for k, other in KINDS.items() if other.pickable]
        raise ConfigError(f"task {task.key}: the scripted operator cannot pick a {kind.name} ({name}) from above; "
                          f"it picks {pickable}")
    if grasp.half_width_m is None:
        return TopDownGrasp(0.0, None, settings.grasp_tcp_height_m + grasp.tcp_offset_m)
    return TopDownGrasp(closing_for_opening(grasp.half_width_m + settings.preshape_margin_m, jaw_open_m),
                        grasp.tcp_offset_m)
