"""The physical check of a world before a run: what a world file can state that its physics then
undoes, found in seconds rather than as a twin that fails every episode without saying why.

Two trials, each a few simulated seconds:

* **At home.** The robot is held at its home pose by its servos for ``HOLD_S`` with its grippers
  open, then for ``HOLD_S`` with them closed (on nothing). Every limited joint of every arm, the
  gripper's fingers and linkages included, must stay within its range (``LIMIT_TOLERANCE`` of the
  range's width beyond it: MuJoCo's limits are soft) and every position finite. Stiff servos on
  light fingers fling them far past their limits; a model whose joints are driven by torque and
  given no ``servo`` sags out of its range.
* **A grasp.** Each object a task's plan picks (``pick: X``, ``turn_upright: X``) rests on the
  table, in the task's placement, at a spot of its start region the arm reaches with its hand
  pointing down (the region's centre if it can, else the nearest point of a grid over it). The
  arm is put there and grasps it as the scripted operator does (``r2s_eval.sim.grasping``, which
  both read): the hand at the yaw the arm holds with its joints nearest home (the object turned
  square to it), the tcp at the operator's grasp height, the jaws at its pre-shape; after
  ``SETTLE_S`` the gripper closes at the operator's rate and stays closed as long, then the hand
  rises ``LIFT_M`` at the operator's lift speed and holds ``HOLD_LIFTED_S``: the object must rise
  with it (to within ``SLIP_M``). Jaws whose collision shapes squeeze the object out, too little
  friction, too weak a gripper or one so stiff that its jaw knocks the object away show here.
  Each arm the task may use is tried (its ``arm``, or every arm for ``nearest`` and
  ``behind_axis``). What it does not try: the operator's approach from above, its aiming error
  and speed jitter, a hand turned off its natural yaw (neighbours, a block's faces at its start
  yaw), the carry to the target and the twin's perturbations and reality effects.

Each problem is one line naming the world key, the arm and the joint or object, and what was
seen, e.g. ``world.robot.arms.left.gripper: left_finger reached 0.17 at home with the gripper
closed, range 0.021..0.057``. ``python -m r2s_eval.world`` runs the check, and the teleop stage
runs it once before it records.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import mujoco
import numpy as np

from r2s_eval.errors import ConfigError
from r2s_eval.sim import assembly
from r2s_eval.sim.arm_ik import ArmIK, top_down_rotation
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.grasping import GraspSettings, natural_yaw, task_grasp, ticks
from r2s_eval.sim.predicates import centre_m
from r2s_eval.sim.reading import WorldError
from r2s_eval.sim.robot import Robot, world_robot
from r2s_eval.sim.tasks import Task, world_tasks

HOLD_S = 1.0  # seconds at home, with the grippers open, then closed
LIMIT_TOLERANCE = 0.1  # share of a joint's range it may pass its limit by (soft limits)
SETTLE_S, HOLD_LIFTED_S = 0.2, 0.3  # the grasp trial's arm settling at the grasp, and its hold once lifted
LIFT_M = 0.05  # how far the hand rises with the object
SLIP_M = 0.015  # how far the object may fall behind the hand and still count as held
FAR_AWAY_M = 5.0  # where a task's other objects are put, out of the trial's way
REGION_GRID = 5  # points per side of the grid searched for a reachable spot


def _arm_joints(model: mujoco.MjModel, robot: Robot) -> dict[str, list[int]]:
    """Per arm, the limited joints of its model (arm, fingers, linkages): those under its root body."""
    out = {}
    for name in robot.arms:
        root = model.body_rootid[model.site_bodyid[model.site(assembly.ee_site(name)).id]]
        out[name] = [j for j in range(model.njnt) if model.jnt_limited[j]
                     and model.body_rootid[model.jnt_bodyid[j]] == root
                     and model.jnt_type[j] in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))]
    return out


def _steps(env: TabletopEnv, seconds: float) -> int:
    return max(1, round(seconds / env.model.opt.timestep))


def home_problems(env: TabletopEnv) -> list[str]:
    """The robot held at home, grippers open then closed: joints past their ranges, or not finite."""
    robot, m, d = env.robot, env.model, env.data
    joints = _arm_joints(m, robot)
    home = {name: arm.home for name, arm in robot.arms.items()}
    problems: dict[tuple[str, int], str] = {}
    for closing, state in ((0.0, "open"), (1.0, "closed")):
        env.apply_action(robot.from_model({name: (q, closing) for name, q in home.items()}))
        low = np.full(m.njnt, np.inf)
        high = np.full(m.njnt, -np.inf)
        d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number = 0
        for _ in range(_steps(env, HOLD_S)):
            mujoco.mj_step(m, d)
            bad = d.warning[mujoco.mjtWarning.mjWARN_BADQACC]
            if bad.number:  # MuJoCo reset the state when it diverged: the joint whose dof blew up
                low[m.dof_jntid[bad.lastinfo]] = np.nan
                break
            q = d.qpos[m.jnt_qposadr]
            low, high = np.minimum(low, q), np.maximum(high, q)
        for name, ids in joints.items():
            arm = robot.arms[name]
            for j in ids:
                if (name, j) in problems:
                    continue
                lo, hi = m.jnt_range[j]
                margin = LIMIT_TOLERANCE * (hi - lo)
                local = m.joint(j).name.removeprefix(arm.named(""))
                key = f"world.robot.arms.{name}.{'joints' if local in arm.joints else 'gripper'}"
                if not (np.isfinite(low[j]) and np.isfinite(high[j])):
                    problems[name, j] = (f"{key}: {local} diverged (the simulation became unstable) at home with "
                                         f"the gripper {state}")
                elif low[j] < lo - margin or high[j] > hi + margin:
                    seen = low[j] if lo - low[j] > high[j] - hi else high[j]
                    problems[name, j] = (f"{key}: {local} reached {seen:.3g} at home with the gripper {state}, "
                                         f"range {lo:.3g}..{hi:.3g}")
    return list(problems.values())


def _region_points(task: Task, name: str) -> list[np.ndarray]:
    """Points of the object's start region (its parent's, for one that starts on another), centre
    first, then by distance from it."""
    region = task.init_regions[name]
    if region.relative_to is not None:
        region = task.init_regions[region.relative_to]
    xs = np.linspace(*region.x_range_m, REGION_GRID)
    ys = np.linspace(*region.y_range_m, REGION_GRID)
    centre = np.array([np.mean(region.x_range_m), np.mean(region.y_range_m)])
    grid = [np.array([x, y]) for x in xs for y in ys]
    return sorted(grid, key=lambda p: float(np.linalg.norm(p - centre)))


def _grasp_problem(env: TabletopEnv, ik: ArmIK, name: str, xy: np.ndarray, settings: GraspSettings) -> str | None:
    """Close the arm's gripper on ``name`` resting at ``xy`` as the operator does and lift it; None
    where the arm does not reach the grasp or the lift with its hand pointing down."""
    robot, m, d, arm = env.robot, env.model, env.data, ik.arm
    others = [n for n in env.task.object_names if n != name]
    poses = {n: (FAR_AWAY_M, FAR_AWAY_M * (1 + i), 0.0) for i, n in enumerate(others)}
    env.reset(object_poses={**poses, name: (float(xy[0]), float(xy[1]), 0.0)}, settle=False, observe=False)
    centre = centre_m(env, name)
    grasp = task_grasp(env.task, name, env.object_dims(name), robot.arms[arm].gripper.jaw_open_m, settings)
    reach = centre[:2] - env.arm_base_positions()[arm][:2]
    yaw = natural_yaw(ik, centre, float(np.arctan2(reach[1], reach[0])))
    R = top_down_rotation(yaw)
    at = np.r_[centre[:2], grasp.tcp_z_m(centre[2], env.table_top_z_m)]
    q_grasp = ik.joints_for(at, R)
    q_lift = None if q_grasp is None else ik.joints_for(at + [0.0, 0.0, LIFT_M], R, seed=q_grasp)
    if q_lift is None:
        return None
    # The object turned with the hand (a block's faces square to the jaws, as the operator turns
    # its hand to them), the arm at the grasp with the jaws pre-shaped.
    env.reset(object_poses={**poses, name: (float(xy[0]), float(xy[1]), yaw)}, settle=False, observe=False)
    command = {n: (a.home, 0.0) for n, a in robot.arms.items()}
    env.pose_robot(robot.from_model({**command, arm: (q_grasp, grasp.preshape)}))

    def step(q: np.ndarray, closing: float, steps: int = 1) -> None:  # control steps, as the operator's
        command[arm] = (q, closing)
        env.apply_action(robot.from_model(command))
        mujoco.mj_step(m, d, nstep=steps * env.n_substeps)

    dt, per_step = env.control_dt_s, ticks(env.control_dt_s)
    step(q_grasp, grasp.preshape, robot.steps_in(SETTLE_S))
    closing, rate = grasp.preshape, settings.gripper_rate_per_step / per_step  # the operator's gripper rate
    while closing < 1.0:
        closing = min(1.0, closing + rate)
        step(q_grasp, closing)
    step(q_grasp, 1.0, settings.close_hold_steps * per_step)
    hand0, obj0 = env.ee_positions()[arm][2], centre_m(env, name)[2]
    n = int(np.ceil(LIFT_M / (settings.lift_speed_m_s * dt)))
    for k in range(1, n + 1):
        step(q_grasp + k / n * (q_lift - q_grasp), 1.0)
    step(q_lift, 1.0, robot.steps_in(HOLD_LIFTED_S))
    hand, obj = env.ee_positions()[arm][2] - hand0, centre_m(env, name)[2] - obj0
    if not np.isfinite(obj) or hand - obj > SLIP_M:
        return (f"world.robot.arms.{arm}.gripper: did not hold {name}: it stayed {100 * (hand - obj):.1f} cm "
                f"below the hand after a {100 * hand:.1f} cm lift")
    return ""


def grasp_problems(robot: Robot, tasks: Mapping[str, Task], settings: GraspSettings | None = None) -> list[str]:
    """Each object a task picks, closed on and lifted by each arm the task may use, as the
    operator's ``settings`` (default: its defaults) grasp it."""
    settings = settings or GraspSettings()
    problems, tried = [], set()
    iks: dict[str, ArmIK] = {}
    home = {name: a.home for name, a in robot.arms.items()}
    for key, task in tasks.items():
        name = task.manipulated
        arms = [task.arm] if task.arm in robot.arms else list(robot.arms)
        todo = [a for a in arms if (a, name, task.placement(name)) not in tried]
        if not todo:
            continue
        env = TabletopEnv(task, cameras=(), robot=robot)
        try:
            reached_by = []
            for arm in todo:
                tried.add((arm, name, task.placement(name)))
                ik = iks.setdefault(arm, ArmIK(robot, arm, home))
                for xy in _region_points(task, name):
                    line = _grasp_problem(env, ik, name, xy, settings)
                    if line is not None:
                        reached_by.append(arm)
                        if line:
                            problems.append(line)
                        break
                else:
                    if task.arm == arm:
                        problems.append(f"world.tasks.{key}.start.{name}: arm {arm} reaches no point of the start "
                                        f"region with its hand pointing down")
            if not reached_by and task.arm not in robot.arms:
                problems.append(f"world.tasks.{key}.start.{name}: no arm reaches any point of the start region "
                                f"with its hand pointing down")
        finally:
            env.close()
    return problems


def world_problems(world: Mapping, tasks: Sequence[str] | None = None,
                   grasp: GraspSettings | None = None) -> list[str]:
    """Every physical problem of ``world`` (a ``world`` config slice), one line each; the grasps of
    the ``tasks`` named (default: all the world's), made with the operator's ``grasp`` settings
    (default: its defaults)."""
    robot, every = world_robot(world), world_tasks(world)
    tasks = {key: every[key] for key in (every if tasks is None else tasks)}
    env = TabletopEnv(next(iter(tasks.values())), cameras=(), robot=robot)
    try:
        env.reset(seed=0, settle=False, observe=False)
        problems = home_problems(env)
    finally:
        env.close()
    return problems + grasp_problems(robot, tasks, grasp)


def check_world(world: Mapping, tasks: Sequence[str] | None = None, grasp: GraspSettings | None = None) -> None:
    """Raise a ``WorldError`` (one problem) or a ``ConfigError`` listing every physical problem of
    ``world`` (grasps: of ``tasks``, with the operator's ``grasp`` settings), one line each; return
    when it has none."""
    lines = world_problems(world, tasks, grasp)
    if len(lines) == 1:
        raise WorldError(*lines[0].split(": ", 1))
    if lines:
        raise ConfigError(f"{len(lines)} physical problems of the world:\n" + "\n".join(f"  - {line}" for line in lines))
