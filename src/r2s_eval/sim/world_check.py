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
  arm is put there, its jaws open on either side of the object's centre (turned square to it),
  the gripper closes, and the hand rises ``LIFT_M``: the object must rise with it (to within
  ``SLIP_M``). Jaws whose collision shapes squeeze the object out, too little friction or too
  weak a gripper show here. Each arm the task may use is tried (its ``arm``, or every arm for
  ``nearest`` and ``behind_axis``).

Each problem is one line naming the world key, the arm and the joint or object, and what was
seen, e.g. ``world.robot.arms.left.gripper: left_finger reached 0.17 at home with the gripper
closed, range 0.021..0.057``. ``python -m r2s_eval.world`` runs the check, and the teleop stage
runs it once before it records.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import mink
import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from r2s_eval.errors import ConfigError
from r2s_eval.sim import assembly
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.predicates import centre_m
from r2s_eval.sim.reading import WorldError
from r2s_eval.sim.robot import Robot, world_robot
from r2s_eval.sim.tasks import Task, world_tasks

HOLD_S = 1.0  # seconds at home, with the grippers open, then closed
LIMIT_TOLERANCE = 0.1  # share of a joint's range it may pass its limit by (soft limits)
SETTLE_S, CLOSE_S, LIFT_S, HOLD_LIFTED_S = 0.2, 0.6, 0.5, 0.3  # the grasp trial's phases
LIFT_M = 0.05  # how far the hand rises with the object
SLIP_M = 0.015  # how far the object may fall behind the hand and still count as held
GRASP_ABOVE_CENTRE_M = 0.006  # the grasp centre this far above the object's centre (fingertips off the table)
IK_ITERATIONS, IK_TOLERANCE_M, IK_TOLERANCE_RAD = 80, 0.002, np.deg2rad(2.0)
FAR_AWAY_M = 5.0  # where a task's other objects are put, out of the trial's way
REGION_GRID = 5  # points per side of the grid searched for a reachable spot


def top_down(yaw_rad: float) -> np.ndarray:
    """A hand frame (columns: approach, jaw axis, third) pointing down, its third axis at ``yaw_rad``."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.column_stack([[0.0, 0.0, -1.0], [-s, c, 0.0], [c, s, 0.0]])


class _Reach:
    """Inverse kinematics of one arm's grasp centre on the robot-only model, from home."""

    def __init__(self, robot: Robot, arm: str):
        self.arm, self.robot = arm, robot
        self.model = assembly.build_robot_model(robot)
        self.site = assembly.ee_site(arm)
        self.qadr = np.array([self.model.joint(robot.arms[arm].named(j)).qposadr[0] for j in robot.arms[arm].joints])
        home = mink.Configuration(self.model).q.copy()
        for name, a in robot.arms.items():
            home[[self.model.joint(a.named(j)).qposadr[0] for j in a.joints]] = a.home
        self.home = home
        self.frame = mink.FrameTask(self.site, "site", position_cost=1.0, orientation_cost=0.5, lm_damping=1e-3)
        self.posture = mink.PostureTask(self.model, cost=1e-3)
        self.posture.set_target(home)
        self.limits = [mink.ConfigurationLimit(self.model)]
        data = mujoco.MjData(self.model)  # where the arm's base stands (its root body, at home)
        data.qpos[:] = home
        mujoco.mj_kinematics(self.model, data)
        self.base_xy = data.xpos[self.model.body_rootid[self.model.site_bodyid[self.model.site(self.site).id]], :2].copy()

    def joints(self, pos: np.ndarray, R: np.ndarray, seed: np.ndarray | None = None) -> np.ndarray | None:
        """The arm's joints that put its grasp centre at ``pos`` turned ``R``; None out of reach."""
        config = mink.Configuration(self.model, self.home if seed is None else seed)
        self.frame.set_target(mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(R), pos))
        dt = self.robot.control_dt_s
        for _ in range(IK_ITERATIONS):
            vel = mink.solve_ik(config, [self.frame, self.posture], dt, solver="daqp", damping=1e-3, limits=self.limits)
            config.integrate_inplace(vel, dt)
        T = config.get_transform_frame_to_world(self.site, "site").as_matrix()
        turn = Rotation.from_matrix(T[:3, :3] @ R.T).magnitude()
        if np.linalg.norm(T[:3, 3] - pos) > IK_TOLERANCE_M or turn > IK_TOLERANCE_RAD:
            return None
        return config.q.copy()

    def grasp(self, centre: np.ndarray) -> tuple[float, np.ndarray, np.ndarray] | None:
        """(hand yaw, joints at the grasp, joints lifted) for a top-down grasp at ``centre``: the
        hand turned by the quarter turn about the reach that keeps the joints nearest home."""
        reach = centre[:2] - self.base_xy
        best = None
        for turn in (0.0, np.pi / 2, np.pi, -np.pi / 2):
            yaw = float(np.arctan2(reach[1], reach[0]) + turn)
            q = self.joints(centre, top_down(yaw))
            if q is None:
                continue
            lifted = self.joints(centre + [0.0, 0.0, LIFT_M], top_down(yaw), seed=q)
            cost = float(np.linalg.norm(q[self.qadr] - self.home[self.qadr]))
            if lifted is not None and (best is None or cost < best[0]):
                best = (cost, yaw, q[self.qadr], lifted[self.qadr])
        return None if best is None else best[1:]


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


def _grasp_problem(env: TabletopEnv, reach: _Reach, name: str, xy: np.ndarray, yaw: float) -> str | None:
    """Close the arm's gripper on ``name`` resting at ``xy`` (turned ``yaw``) and lift it."""
    robot, m, d, arm = env.robot, env.model, env.data, reach.arm
    others = [n for n in env.task.object_names if n != name]
    poses = {n: (FAR_AWAY_M, FAR_AWAY_M * (1 + i), 0.0) for i, n in enumerate(others)}
    env.reset(object_poses={**poses, name: (float(xy[0]), float(xy[1]), yaw)}, settle=False, observe=False)
    centre = centre_m(env, name) + [0.0, 0.0, GRASP_ABOVE_CENTRE_M]
    found = reach.grasp(centre)
    if found is None:
        return None
    yaw, q_grasp, q_lift = found
    # The object turned with the hand (its faces square to the jaws), the arm at the grasp.
    env.reset(object_poses={**poses, name: (float(xy[0]), float(xy[1]), yaw)}, settle=False, observe=False)
    command = {n: (a.home, 0.0) for n, a in robot.arms.items()}
    env.pose_robot(robot.from_model({**command, arm: (q_grasp, 0.0)}))

    def hold(q: np.ndarray, closing: float, seconds: float) -> None:
        command[arm] = (q, closing)
        env.apply_action(robot.from_model(command))
        mujoco.mj_step(m, d, nstep=_steps(env, seconds))

    hold(q_grasp, 0.0, SETTLE_S)
    hold(q_grasp, 1.0, CLOSE_S)
    hand0, obj0 = env.ee_positions()[arm][2], centre_m(env, name)[2]
    ramp = _steps(env, LIFT_S) // 10
    for s in np.linspace(0.1, 1.0, 10):
        hold(q_grasp + s * (q_lift - q_grasp), 1.0, ramp * m.opt.timestep)
    hold(q_lift, 1.0, HOLD_LIFTED_S)
    hand, obj = env.ee_positions()[arm][2] - hand0, centre_m(env, name)[2] - obj0
    if not np.isfinite(obj) or hand - obj > SLIP_M:
        return (f"world.robot.arms.{arm}.gripper: did not hold {name}: it stayed {100 * (hand - obj):.1f} cm "
                f"below the hand after a {100 * hand:.1f} cm lift")
    return ""


def grasp_problems(robot: Robot, tasks: Mapping[str, Task]) -> list[str]:
    """Each object a task picks, closed on and lifted by each arm the task may use."""
    problems, tried = [], set()
    reaches: dict[str, _Reach] = {}
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
                reach = reaches.setdefault(arm, _Reach(robot, arm))
                for xy in _region_points(task, name):
                    line = _grasp_problem(env, reach, name, xy, 0.0)
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


def world_problems(world: Mapping, tasks: Sequence[str] | None = None) -> list[str]:
    """Every physical problem of ``world`` (a ``world`` config slice), one line each; the grasps of
    the ``tasks`` named (default: all the world's)."""
    robot, every = world_robot(world), world_tasks(world)
    tasks = {key: every[key] for key in (every if tasks is None else tasks)}
    env = TabletopEnv(next(iter(tasks.values())), cameras=(), robot=robot)
    try:
        env.reset(seed=0, settle=False, observe=False)
        problems = home_problems(env)
    finally:
        env.close()
    return problems + grasp_problems(robot, tasks)


def check_world(world: Mapping, tasks: Sequence[str] | None = None) -> None:
    """Raise a ``WorldError`` (one problem) or a ``ConfigError`` listing every physical problem of
    ``world`` (grasps: of ``tasks``), one line each; return when it has none."""
    lines = world_problems(world, tasks)
    if len(lines) == 1:
        raise WorldError(*lines[0].split(": ", 1))
    if lines:
        raise ConfigError(f"{len(lines)} physical problems of the world:\n" + "\n".join(f"  - {line}" for line in lines))
