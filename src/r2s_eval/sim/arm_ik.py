"""Differential IK (mink) of one arm's grasp centre on the robot-only model: the scripted operator
(``r2s_eval.twin.operator``) steers its hand with it and the world check (``world_check``) poses
its grasp trial with it, so the two reach, and turn the hand, alike."""

from __future__ import annotations

import mink
import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from r2s_eval.sim import assembly
from r2s_eval.sim.robot import Robot

PROBE_ITERATIONS = 60  # IK iterations of a reach probe
PROBE_TOLERANCE_M, PROBE_TOLERANCE_RAD = 0.002, np.deg2rad(2.0)  # a probe closer than this reaches

_ROBOT_MODELS: dict[int, tuple[Robot, mujoco.MjModel]] = {}


def top_down_rotation(approach_yaw_rad: float) -> np.ndarray:
    """Gripper frame pointing down (x = -z world), with its z axis along the reach direction."""
    c, s = np.cos(approach_yaw_rad), np.sin(approach_yaw_rad)
    return np.column_stack([[0.0, 0.0, -1.0], [-s, c, 0.0], [c, s, 0.0]])


def robot_model(robot: Robot) -> mujoco.MjModel:
    """The robot-only model of ``robot`` (objects do not matter for kinematics), compiled once."""
    if id(robot) not in _ROBOT_MODELS:
        _ROBOT_MODELS[id(robot)] = (robot, assembly.build_robot_model(robot))  # holds robot: its id stays its own
    return _ROBOT_MODELS[id(robot)][1]


class ArmIK:
    """Differential IK for one arm on the robot-only model, steering the arm's grasp-centre site."""

    def __init__(self, robot: Robot, arm: str, q_init: dict[str, np.ndarray]):
        self.arm, self.robot = arm, robot
        self.model = robot_model(robot)
        self.configuration = mink.Configuration(self.model)
        self.frame_task = mink.FrameTask(
            frame_name=assembly.ee_site(arm), frame_type="site", position_cost=1.0, orientation_cost=0.5, lm_damping=1e-3
        )
        self.posture_task = mink.PostureTask(self.model, cost=1e-3)
        self.limits = [mink.ConfigurationLimit(self.model)]
        self._qadr = {name: np.array([self.model.joint(a.named(j)).qposadr[0] for j in a.joints])
                      for name, a in robot.arms.items()}
        q = self.configuration.q.copy()
        for name in robot.arms:
            q[self._qadr[name]] = q_init[name]
        self.configuration.update(q)
        home = q.copy()
        for name, a in robot.arms.items():
            home[self._qadr[name]] = a.home
        self.posture_task.set_target(home)
        self._probe = mink.Configuration(self.model, q)  # a scratch configuration for reach probes

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        T = self.configuration.get_transform_frame_to_world(assembly.ee_site(self.arm), "site").as_matrix()
        return T[:3, 3].copy(), T[:3, :3].copy()

    def joints_for(self, pos_world_m: np.ndarray, R_world: np.ndarray,
                   seed: np.ndarray | None = None) -> np.ndarray | None:
        """The arm's joints that put its grasp centre at the pose, solved from the commanded
        configuration (which stays as it is; ``seed``: from these arm joints instead); None when the
        pose is out of the arm's reach."""
        q = self.configuration.q.copy()
        if seed is not None:
            q[self._qadr[self.arm]] = seed
        self._probe.update(q)
        self.frame_task.set_target(mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(R_world), pos_world_m))
        for _ in range(PROBE_ITERATIONS):
            vel = mink.solve_ik(self._probe, [self.frame_task, self.posture_task], self.robot.control_dt_s,
                                solver="daqp", damping=1e-3, limits=self.limits)
            self._probe.integrate_inplace(vel, self.robot.control_dt_s)
        T = self._probe.get_transform_frame_to_world(assembly.ee_site(self.arm), "site").as_matrix()
        turn = Rotation.from_matrix(T[:3, :3] @ R_world.T).magnitude()
        if np.linalg.norm(T[:3, 3] - pos_world_m) > PROBE_TOLERANCE_M or turn > PROBE_TOLERANCE_RAD:
            return None
        return self._probe.q[self._qadr[self.arm]].copy()

    def highest_z(self, xy: np.ndarray, z_low: float, z_high: float, R_world: np.ndarray) -> float:
        """``z_high`` if the hand reaches it over ``xy`` (orientation ``R_world``), else the highest
        height above ``z_low`` it reaches (to 5 mm): a small arm cannot lift a top-down hand high.
        Where the hand reaches neither (a wrist at its limit), the height is not what limits it."""
        if (self.joints_for(np.r_[xy, z_high], R_world) is not None
                or self.joints_for(np.r_[xy, z_low], R_world) is None):
            return z_high
        while z_high - z_low > 0.005:
            mid = 0.5 * (z_low + z_high)
            z_low, z_high = (mid, z_high) if self.joints_for(np.r_[xy, mid], R_world) is not None else (z_low, mid)
        return z_low

    def solve(self, pos_world_m: np.ndarray, R_world: np.ndarray, iterations: int) -> np.ndarray:
        """Move the commanded configuration toward the target; returns the arm's joint targets."""
        target = mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(R_world), np.asarray(pos_world_m))
        self.frame_task.set_target(target)
        dt = self.robot.control_dt_s
        for _ in range(iterations):
            vel = mink.solve_ik(
                self.configuration, [self.frame_task, self.posture_task], dt, solver="daqp", damping=1e-3,
                limits=self.limits,
            )
            self.configuration.integrate_inplace(vel, dt)
        return self.configuration.q[self._qadr[self.arm]].copy()
