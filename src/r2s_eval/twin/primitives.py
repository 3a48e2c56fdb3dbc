"""The scripted operator's plan primitives: what each does, built from a small operator interface.

A task's plan (``world.tasks.<key>.plan``, checked against ``r2s_eval.sim.plans``) names a pick
and one place primitive, or one primitive alone. Each primitive here is registered under its
name in that table (``PRIMITIVES``; the two must list the same names, checked at import) and
builds its part of the plan from what the operator offers (``Operator``): the scene, its
settings and random generator, where it commands the hand, its free-space moves and speeds.

* a pick primitive (``pick``): ``(op, obj) -> (grasp_tcp_z_m, open_cmd)``, how the hand takes
  ``obj``: the tcp height when closing and the gripper's pre-shape;
* a place primitive: ``(op, held, target) -> (place_centre_m, hover_z_m | None)``, where the held
  object's centre is when released, and how high the hand hovers (None: above the object);
* a primitive alone (``turn_upright``): ``(op, obj) -> plan steps``.

A plan step is a function that, called when the operator reaches it, returns its segments (tcp
targets seen from the scene as it is then).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.grasping import ON_SIDE_ABOVE_CENTRE_M
from r2s_eval.sim.plans import PLAN_PRIMITIVES
from r2s_eval.sim.predicates import centre_m
from r2s_eval.sim.tasks import Task


@dataclass
class Segment:
    """Move the tcp to ``pos_world_m`` and the gripper to ``gripper``, then hold ``hold_steps``."""

    name: str  # the phase the operator is in while it runs
    pos_world_m: np.ndarray
    gripper: float
    speed_m_s: float
    hold_steps: int = 0
    R_world: np.ndarray | None = None  # gripper orientation to reach; None keeps the current one
    settle_m: float | None = None  # also wait until the real tcp is this close to the target


PlanStep = Callable[[], list[Segment]]


class Operator(Protocol):
    """What a primitive uses of the scripted operator (``r2s_eval.twin.operator.ScriptedOperator``)."""

    env: TabletopEnv
    task: Task
    cfg: Any  # its OperatorConfig
    rng: np.random.Generator
    arm: str  # the arm it commands

    @property
    def cmd_pos(self) -> np.ndarray: ...  # the commanded tcp position (world)
    @property
    def R_cmd(self) -> np.ndarray: ...  # the commanded hand orientation
    def aim(self) -> np.ndarray: ...  # a horizontal aiming error (m)
    def speed(self, base_m_s: float) -> float: ...  # a segment's speed about ``base_m_s``
    def free_move(self, name: str, pos_world_m: np.ndarray, gripper: float) -> list[Segment]: ...
    def reachable_z(self, xys, z: float) -> float: ...
    def object_height_m(self, name: str) -> float: ...
    def grasp(self, name: str) -> tuple[Height, float]: ...  # how the hand takes an object from above
    def resting_centre_on(self, held: str, support: str) -> Place: ...  # held object's centre on a support
    def do_next(self, steps: list[PlanStep]) -> None: ...  # do these plan steps before the rest


Height = Callable[["Operator"], float]  # a tcp height (world), read from the scene when called
Place = Callable[["Operator"], np.ndarray]  # where the held object's centre is when released (world)


@dataclass(frozen=True)
class PickPlace:
    """One pick-and-place: grasp ``obj`` top-down, carry it, lower it, let go.

    ``grasp_tcp_z_m(op)``: tcp height (world) when closing; ``place_centre_m(op)``: where
    the object's centre should be when released (world, recomputed when lowering);
    ``open_cmd``: gripper pre-shape while approaching (0 = fully open).
    """

    obj: str
    grasp_tcp_z_m: Height
    place_centre_m: Place
    open_cmd: float = 0.0
    hover_z_m: Height | None = None


PRIMITIVES: dict[str, Callable] = {}


def primitive(name: str):
    """Register the decorated function as the implementation of plan primitive ``name``."""
    if name not in PLAN_PRIMITIVES:
        raise ImportError(f"plan primitive {name!r} is not in r2s_eval.sim.plans.PLAN_PRIMITIVES")

    def register(fn):
        PRIMITIVES[name] = fn
        return fn

    return register


def plan(op: Operator) -> list[PlanStep]:
    """The steps of the operator's task plan: a pick and a place, or a primitive alone."""
    steps = [next(iter(step.items())) for step in op.task.plan]
    if len(steps) == 1:
        (name, obj), = steps
        return PRIMITIVES[name](op, obj)
    (pick, held), (place, target) = steps
    grasp_z, open_cmd = PRIMITIVES[pick](op, held)
    centre, hover = PRIMITIVES[place](op, held, target)
    return pick_and_place(op, PickPlace(held, grasp_z, centre, open_cmd, hover))


def pick_and_place(op: Operator, pp: PickPlace) -> list[PlanStep]:
    """pregrasp (above the object, gripper pre-shaped) -> approach (down) -> close -> [regrasp:
    open, back off, re-approach, close] -> lift -> carry (over the target, corrected for where the
    object sits in the hand) -> lower -> release -> retreat."""
    cfg, env = op.cfg, op.env
    table_z = env.table_top_z_m
    open_cmd = pp.open_cmd

    def hover_z(xy: np.ndarray) -> float:
        if pp.hover_z_m is not None:
            z = pp.hover_z_m(op)
        else:
            z = centre_m(env, pp.obj)[2] + 0.5 * op.object_height_m(pp.obj) + cfg.hover_above_cup_m
        return op.reachable_z([xy], z)

    def pregrasp():
        obj = centre_m(env, pp.obj)
        xy = obj[:2] + op.aim()
        return op.free_move("pregrasp", np.r_[xy, hover_z(xy)], open_cmd)

    def approach():
        obj = centre_m(env, pp.obj)  # re-aim on the object as seen now
        return [Segment("approach", np.r_[obj[:2] + op.aim(), pp.grasp_tcp_z_m(op)], open_cmd,
                        op.speed(cfg.fine_speed_m_s), settle_m=cfg.settle_m)]

    def close():
        segs = close_only()
        if op.rng.random() < cfg.regrasp_prob:
            backoff = op.cmd_pos + np.array([0.0, 0.0, 0.04])
            segs += [
                Segment("regrasp_open", op.cmd_pos.copy(), open_cmd, cfg.fine_speed_m_s, hold_steps=1),
                Segment("regrasp_backoff", backoff, open_cmd, op.speed(cfg.fine_speed_m_s)),
            ]
            op.do_next([approach, close_only])
        return segs

    def close_only():
        return [Segment("close", op.cmd_pos.copy(), 1.0, cfg.fine_speed_m_s, hold_steps=cfg.close_hold_steps)]

    def lift():  # as high as the carry over to the target allows
        xy, target = op.cmd_pos[:2], pp.place_centre_m(op)[:2]
        carry_z = op.reachable_z([xy, 0.5 * (xy + target), target], table_z + cfg.carry_tcp_height_m)
        return [Segment("lift", np.r_[xy, carry_z], 1.0, op.speed(cfg.lift_speed_m_s))]

    def carry():
        # Where the object sits in the hand, as seen: place the object, not the tcp.
        tcp_minus_obj = env.ee_positions()[op.arm] - centre_m(env, pp.obj)
        target_xy = pp.place_centre_m(op)[:2] + tcp_minus_obj[:2]
        return op.free_move("carry", np.r_[target_xy, op.cmd_pos[2]], 1.0)

    def lower():
        obj, target = centre_m(env, pp.obj), pp.place_centre_m(op)
        tcp_minus_obj = env.ee_positions()[op.arm] - obj
        target_xy = op.cmd_pos[:2] + (target[:2] - obj[:2])  # final horizontal correction
        return [Segment("lower", np.r_[target_xy, target[2] + tcp_minus_obj[2]], 1.0, op.speed(cfg.fine_speed_m_s))]

    def release():
        return [Segment("release", op.cmd_pos.copy(), open_cmd, cfg.fine_speed_m_s, hold_steps=2)]

    def retreat():  # up; what the arm cannot rise it backs off towards its base
        up = op.cmd_pos + np.array([0.0, 0.0, cfg.retreat_m])
        up[2] = op.reachable_z([up[:2]], up[2])
        segments = [Segment("retreat", up, open_cmd, op.speed(cfg.free_speed_m_s))]
        if up[2] < op.cmd_pos[2] + cfg.retreat_m:
            back = env.arm_base_positions()[op.arm][:2] - up[:2]
            back *= (op.cmd_pos[2] + cfg.retreat_m - up[2]) / np.linalg.norm(back)
            segments.append(Segment("retreat_back", up + np.r_[back, 0.0], open_cmd, op.speed(cfg.free_speed_m_s)))
        return segments

    return [pregrasp, approach, close, lift, carry, lower, release, retreat]


@primitive("pick")
def pick(op: Operator, obj: str) -> tuple[Height, float]:
    """From above, as the operator takes an object of its kind (``ScriptedOperator.grasp``)."""
    return op.grasp(obj)


@primitive("place_on")
def place_on(op: Operator, held: str, support: str) -> tuple[Place, None]:
    """The held object's bottom a little above the support's top face, over its centre."""
    return op.resting_centre_on(held, support), None


@primitive("place_in")
def place_in(op: Operator, held: str, container: str) -> tuple[Place, None]:
    """The held object just above the container's rim, over its centre (it drops in)."""
    env, cfg = op.env, op.cfg
    rim_h, held_h = op.object_height_m(container), op.object_height_m(held)

    def place(op):
        pos = env.object_state(container)["pos_world_m"]
        return np.r_[pos[:2], pos[2] + rim_h + held_h / 2 + cfg.drop_height_m]

    return place, None


@primitive("place_over")
def place_over(op: Operator, held: str, covered: str) -> tuple[Place, None]:
    """The held (upside-down) object's rim just above the table, centred on the covered one."""
    env, cfg = op.env, op.cfg
    held_h = op.object_height_m(held)

    def place(op):
        return np.r_[centre_m(op.env, covered)[:2], env.table_top_z_m + cfg.place_clearance_m + held_h / 2]

    return place, None


@primitive("put_down_beside")
def put_down_beside(op: Operator, held: str, other: str) -> tuple[Place, Height]:
    """On the table beside ``other`` (a box), towards the table's centre line; hovering high
    enough that the fingertips clear its walls."""
    env, cfg = op.env, op.cfg
    box = env.object_dims(other)
    held_half_diag = env.object_dims(held)["size_m"] / np.sqrt(2)
    box_pos = env.object_state(other)["pos_world_m"]
    # A box on the centre line: the side away from the arm's base (an arm on the line too: -y).
    base_y = env.arm_base_positions()[op.arm][1]
    side = -np.sign(box_pos[1]) if abs(box_pos[1]) > 0.03 else (1.0 if base_y < -0.03 else -1.0)
    box_yaw = env.object_poses()[other]["yaw_rad"]
    c, s = np.cos(box_yaw), np.sin(box_yaw)
    corners = np.array([[c * sx * box["length_m"] / 2 - s * sy * box["width_m"] / 2,
                         s * sx * box["length_m"] / 2 + c * sy * box["width_m"] / 2] for sx in (-1, 1) for sy in (-1, 1)])
    reach_y = float(np.max(corners[:, 1] * side)) + held_half_diag + cfg.put_down_margin_m
    target_xy = box_pos[:2] + np.array([0.0, side * reach_y])

    def place(op):
        return np.r_[target_xy, env.table_top_z_m + cfg.place_clearance_m + env.object_dims(held)["size_m"] / 2]

    hover = lambda op: env.table_top_z_m + box["height_m"] + cfg.hover_above_cup_m + 0.03
    return place, hover


@primitive("turn_upright")
def turn_upright(op: Operator, name: str) -> list[PlanStep]:
    """Grasp the lying object (a cup) across its middle, lift, pitch the hand 90 deg, set it down, let go."""
    env, cfg = op.env, op.cfg
    table_z = env.table_top_z_m
    dims = env.object_dims(name)
    axis_yaw = env.object_poses()[name]["yaw_rad"]
    axis = np.array([np.cos(axis_yaw), np.sin(axis_yaw), 0.0])
    # Rotating about (axis x up) by +90 deg turns the cup's axis (bottom -> opening) upwards.
    R_turn = Rotation.from_rotvec(np.cross(axis, [0.0, 0.0, 1.0]) * (np.pi / 2)).as_matrix()

    def pregrasp():
        cup = centre_m(env, name)
        return op.free_move("pregrasp", np.r_[cup[:2] + op.aim(), table_z + 2 * dims["radius_m"] + cfg.hover_above_cup_m], 0.0)

    def approach():
        cup = centre_m(env, name)
        return [Segment("approach", np.r_[cup[:2] + op.aim(), cup[2] + ON_SIDE_ABOVE_CENTRE_M], 0.0,
                        op.speed(cfg.fine_speed_m_s), settle_m=cfg.settle_m)]

    def close():
        return [Segment("close", op.cmd_pos.copy(), 1.0, cfg.fine_speed_m_s, hold_steps=cfg.close_hold_steps)]

    def lift():
        return [Segment("lift", np.r_[op.cmd_pos[:2], table_z + cfg.upright_lift_tcp_height_m], 1.0,
                        op.speed(cfg.lift_speed_m_s))]

    def turn():
        return [Segment("turn", op.cmd_pos.copy(), 1.0, cfg.fine_speed_m_s, R_world=R_turn @ op.R_cmd)]

    def lower():
        bottom_z = env.object_state(name)["pos_world_m"][2]  # body origin = bottom centre
        drop = bottom_z - (table_z + cfg.place_clearance_m)
        return [Segment("lower", op.cmd_pos - np.array([0.0, 0.0, drop]), 1.0, op.speed(cfg.fine_speed_m_s))]

    def release():
        return [Segment("release", op.cmd_pos.copy(), 0.0, cfg.fine_speed_m_s, hold_steps=2)]

    def retreat():  # back off along the hand's approach axis, then up
        back = op.cmd_pos - op.R_cmd[:, 0] * 0.08
        return [Segment("retreat", back, 0.0, op.speed(cfg.fine_speed_m_s)),
                Segment("retreat_up", back + np.array([0.0, 0.0, 0.06]), 0.0, op.speed(cfg.free_speed_m_s))]

    return [pregrasp, approach, close, lift, turn, lower, release, retreat]


if set(PRIMITIVES) != set(PLAN_PRIMITIVES):
    raise ImportError(f"the plan primitives the task check accepts {sorted(PLAN_PRIMITIVES)} and those the "
                      f"operator implements {sorted(PRIMITIVES)} differ")
