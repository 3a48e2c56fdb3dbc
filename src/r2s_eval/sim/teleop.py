"""Scripted teleoperator: end-effector targets -> differential IK (mink) -> joint targets.

Interface
---------
``op = make_operator(task, env, rng, cfg)`` after ``env.reset(...)``; then each
control step ``action = op.act(obs)`` (14-D, the env's action layout) until
``op.done``. ``run_episode(env, op, max_steps)`` does that loop and returns the
list of ``(obs, action)`` pairs, ``obs`` being the observation the action was
chosen from.

What the operator uses: the measured robot state from ``obs`` and the scene
as a person watching it would see it (true object poses from
``env.object_poses()``, object sizes, where its gripper is). It commands one
arm (the task's ``arm`` rule), keeps the other at its home pose, and keeps
its own commanded joint configuration as the IK seed, as a teleoperation
rig does.

Phases for ``cup_on_plate``: pregrasp (above the cup) -> approach (down) ->
close -> [regrasp: open, back off, re-approach, close] -> lift -> carry
(over the plate, corrected for where the cup sits in the hand) -> lower ->
release -> retreat.

Human-like variability (seeded by ``rng``): per-segment speed factor, short
pauses, overshoot-and-correct on free-space moves, millimetre aiming error,
and an occasional regrasp. Episodes last 6.5-10 s (65-100 control steps).

Success rate: ``python -m r2s_eval.sim.teleop --episodes 20 [--twin]``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mink
import numpy as np

from r2s_eval.sim import world
from r2s_eval.sim.env import ACTION_DIM, TabletopEnv
from r2s_eval.sim.tasks import Task, get_task


@dataclass(frozen=True)
class OperatorConfig:
    free_speed_m_s: float = 0.20  # tcp speed in free space
    fine_speed_m_s: float = 0.10  # tcp speed near objects (approach, lower)
    speed_jitter_rel: float = 0.25  # per-segment speed factor U(1 -/+ jitter)
    gripper_rate_per_step: float = 0.35  # normalised gripper command change per step
    pause_prob: float = 0.15  # chance of a pause before a segment
    pause_steps: tuple[int, int] = (1, 3)
    overshoot_prob: float = 0.3  # chance per free-space move
    overshoot_m: tuple[float, float] = (0.01, 0.025)
    aim_error_m: float = 0.003  # std of the horizontal aiming error at grasp
    regrasp_prob: float = 0.1
    hover_above_cup_m: float = 0.06  # fingertips clearance above the rim at pregrasp
    grasp_tcp_height_m: float = 0.05  # tcp above the table when closing on the cup
    carry_tcp_height_m: float = 0.18  # tcp above the table while carrying
    place_clearance_m: float = 0.006  # cup bottom above the plate when released
    retreat_m: float = 0.10
    ik_iterations: int = 4
    max_steps_per_segment: int = 60


@dataclass
class Segment:
    """Move the tcp to ``pos_world_m`` and the gripper to ``gripper``, then hold ``hold_steps``."""

    name: str
    pos_world_m: np.ndarray
    gripper: float
    speed_m_s: float
    hold_steps: int = 0


def top_down_rotation(approach_yaw_rad: float) -> np.ndarray:
    """Gripper frame pointing down (x = -z world), with its z axis along the reach direction."""
    c, s = np.cos(approach_yaw_rad), np.sin(approach_yaw_rad)
    return np.column_stack([[0.0, 0.0, -1.0], [-s, c, 0.0], [c, s, 0.0]])


class ArmIK:
    """Differential IK for one arm on a robot-only model (objects do not matter for kinematics)."""

    def __init__(self, arm: str, q_init_14: np.ndarray):
        self.arm = arm
        self.model = world.build_robot_model()
        self.configuration = mink.Configuration(self.model)
        self.frame_task = mink.FrameTask(
            frame_name=f"{arm}_tcp", frame_type="site", position_cost=1.0, orientation_cost=0.5, lm_damping=1e-3
        )
        self.posture_task = mink.PostureTask(self.model, cost=1e-3)
        self.limits = [mink.ConfigurationLimit(self.model)]
        self._qadr = {
            a: np.array([self.model.joint(f"{a}_{j}").qposadr[0] for j in world.ARM_JOINTS]) for a in world.ARMS
        }
        q = self.configuration.q.copy()
        for i, a in enumerate(world.ARMS):
            q[self._qadr[a]] = q_init_14[7 * i : 7 * i + 6]
        self.configuration.update(q)
        home = q.copy()
        for a in world.ARMS:
            home[self._qadr[a]] = world.home_arm_q(a)
        self.posture_task.set_target(home)

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        T = self.configuration.get_transform_frame_to_world(f"{self.arm}_tcp", "site").as_matrix()
        return T[:3, 3].copy(), T[:3, :3].copy()

    def solve(self, pos_world_m: np.ndarray, R_world: np.ndarray, iterations: int) -> np.ndarray:
        """Move the commanded configuration toward the target; returns the arm's 6 joint targets."""
        target = mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(R_world), np.asarray(pos_world_m))
        self.frame_task.set_target(target)
        dt = world.CONTROL_DT_S
        for _ in range(iterations):
            vel = mink.solve_ik(
                self.configuration, [self.frame_task, self.posture_task], dt, solver="daqp", damping=1e-3,
                limits=self.limits,
            )
            self.configuration.integrate_inplace(vel, dt)
        return self.configuration.q[self._qadr[self.arm]].copy()


class ScriptedOperator:
    """Phase machine over tcp segments; see module docstring."""

    def __init__(self, task: Task, env: TabletopEnv, rng: np.random.Generator, cfg: OperatorConfig | None = None):
        self.task, self.env, self.rng = task, env, rng
        self.cfg = cfg or OperatorConfig()
        self.done = False
        self.phase = "start"
        self._plan: list[Callable[[], list[Segment]]] = []
        self._queue: list[Segment] = []
        self._segment: Segment | None = None
        self._segment_steps = 0
        self._pause_steps = 0
        self._hold_left = 0
        self._ik: ArmIK | None = None
        self._action: np.ndarray | None = None
        self._cmd_pos: np.ndarray | None = None
        self._gripper_cmd = 0.0
        self.arm = self._choose_arm()
        self._plan = PLANS[task.key](self)

    # ------------------------------------------------------------ scene reads (what a person sees)
    def _obj_pos(self, name: str) -> np.ndarray:
        return self.env.object_poses()[name]["pos_world_m"].copy()

    def _choose_arm(self) -> str:
        if self.task.arm in world.ARMS:
            return self.task.arm
        poses = self.env.object_poses()
        mid_y = np.mean([p["pos_world_m"][1] for p in poses.values()])
        bases = self.env.arm_base_positions()
        return min(world.ARMS, key=lambda a: abs(bases[a][1] - mid_y))

    def _speed(self, base_m_s: float) -> float:
        j = self.cfg.speed_jitter_rel
        return base_m_s * self.rng.uniform(1.0 - j, 1.0 + j)

    def _free_move(self, name: str, pos_world_m: np.ndarray, gripper: float) -> list[Segment]:
        """A free-space move, sometimes overshooting horizontally and correcting."""
        segments = []
        if self.rng.random() < self.cfg.overshoot_prob and self._cmd_pos is not None:
            direction = pos_world_m - self._cmd_pos
            direction[2] = 0.0
            norm = np.linalg.norm(direction)
            if norm > 0.03:
                over = pos_world_m + direction / norm * self.rng.uniform(*self.cfg.overshoot_m)
                segments.append(Segment(f"{name}_overshoot", over, gripper, self._speed(self.cfg.free_speed_m_s)))
        segments.append(Segment(name, pos_world_m, gripper, self._speed(self.cfg.free_speed_m_s)))
        return segments

    # ------------------------------------------------------------ control loop
    def act(self, obs: dict) -> np.ndarray:
        state = np.asarray(obs["observation.state"], dtype=float)
        if self._ik is None:
            self._start(state)
        if not self.done:
            self._advance()
        return self._action.copy()

    def _start(self, state: np.ndarray) -> None:
        self._ik = ArmIK(self.arm, state)
        self._cmd_pos, _ = self._ik.tcp_pose()
        bases = self.env.arm_base_positions()
        cup_xy = self._obj_pos(self.task.objects[0].name)[:2]
        reach = cup_xy - bases[self.arm][:2]
        self._R_cmd = top_down_rotation(float(np.arctan2(reach[1], reach[0])))
        self._action = np.zeros(ACTION_DIM)
        for i, a in enumerate(world.ARMS):
            self._action[7 * i : 7 * i + 6] = state[7 * i : 7 * i + 6] if a == self.arm else world.home_arm_q(a)
            self._action[7 * i + 6] = 0.0
        self._arm_slice = slice(7 * world.ARMS.index(self.arm), 7 * world.ARMS.index(self.arm) + 6)
        self._grip_index = 7 * world.ARMS.index(self.arm) + 6

    def _next_segment(self) -> bool:
        while not self._queue:
            if not self._plan:
                return False
            self._queue = self._plan.pop(0)()
        self._segment = self._queue.pop(0)
        self.phase = self._segment.name
        self._segment_steps = 0
        self._hold_left = self._segment.hold_steps
        if self.rng.random() < self.cfg.pause_prob:
            self._pause_steps = int(self.rng.integers(self.cfg.pause_steps[0], self.cfg.pause_steps[1] + 1))
        return True

    def _advance(self) -> None:
        if self._segment is None and not self._next_segment():
            self.done = True
            return
        if self._pause_steps > 0:  # operator hesitates: keep the last command
            self._pause_steps -= 1
            return
        seg = self._segment
        self._segment_steps += 1
        delta = seg.pos_world_m - self._cmd_pos
        dist = float(np.linalg.norm(delta))
        max_step = seg.speed_m_s * world.CONTROL_DT_S
        self._cmd_pos = seg.pos_world_m.copy() if dist <= max_step else self._cmd_pos + delta / dist * max_step
        rate = self.cfg.gripper_rate_per_step
        self._gripper_cmd += float(np.clip(seg.gripper - self._gripper_cmd, -rate, rate))
        self._action[self._arm_slice] = self._ik.solve(self._cmd_pos, self._R_cmd, self.cfg.ik_iterations)
        self._action[self._grip_index] = self._gripper_cmd
        arrived = dist <= max_step and abs(seg.gripper - self._gripper_cmd) < 1e-9
        if arrived:
            if self._hold_left > 0:
                self._hold_left -= 1
            else:
                self._segment = None
        elif self._segment_steps > self.cfg.max_steps_per_segment:
            self._segment = None  # give up on an unreachable target


# ---------------------------------------------------------------- task plans
def _cup_on_plate_plan(op: ScriptedOperator) -> list[Callable[[], list[Segment]]]:
    cfg, env = op.cfg, op.env
    table_z = env.table_top_z_m
    cup_h = env.object_dims("cup")["height_m"]
    plate_top_m = env.object_dims("plate")["thickness_m"]
    grasp_z = table_z + cfg.grasp_tcp_height_m
    hover_z = table_z + cup_h + cfg.hover_above_cup_m
    state: dict = {}

    def aim() -> np.ndarray:
        return op.rng.normal(0.0, cfg.aim_error_m, 2)

    def pregrasp():
        cup = op._obj_pos("cup")
        return op._free_move("pregrasp", np.r_[cup[:2] + aim(), hover_z], 0.0)

    def approach():
        cup = op._obj_pos("cup")  # re-aim on the cup as seen now
        return [Segment("approach", np.r_[cup[:2] + aim(), grasp_z], 0.0, op._speed(cfg.fine_speed_m_s))]

    def close():
        segs = [Segment("close", op._cmd_pos.copy(), 1.0, cfg.fine_speed_m_s, hold_steps=3)]
        if op.rng.random() < cfg.regrasp_prob:
            backoff = op._cmd_pos + np.array([0.0, 0.0, 0.04])
            segs += [
                Segment("regrasp_open", op._cmd_pos.copy(), 0.0, cfg.fine_speed_m_s, hold_steps=1),
                Segment("regrasp_backoff", backoff, 0.0, op._speed(cfg.fine_speed_m_s)),
            ]
            op._plan[:0] = [approach, close_only]
        return segs

    def close_only():
        return [Segment("close", op._cmd_pos.copy(), 1.0, cfg.fine_speed_m_s, hold_steps=3)]

    def lift():
        return [Segment("lift", np.r_[op._cmd_pos[:2], table_z + cfg.carry_tcp_height_m], 1.0,
                        op._speed(cfg.fine_speed_m_s * 1.5))]

    def carry():
        # Where the cup sits in the hand, as seen: place the cup, not the tcp, over the plate.
        cup, plate = op._obj_pos("cup"), op._obj_pos("plate")
        state["tcp_minus_cup"] = env.ee_positions()[op.arm] - cup
        target_xy = plate[:2] + state["tcp_minus_cup"][:2]
        return op._free_move("carry", np.r_[target_xy, op._cmd_pos[2]], 1.0)

    def lower():
        cup, plate = op._obj_pos("cup"), op._obj_pos("plate")
        tcp_minus_cup = env.ee_positions()[op.arm] - cup
        target_xy = op._cmd_pos[:2] + (plate[:2] - cup[:2])  # final horizontal correction
        target_z = plate[2] + plate_top_m + cfg.place_clearance_m + tcp_minus_cup[2]
        return [Segment("lower", np.r_[target_xy, target_z], 1.0, op._speed(cfg.fine_speed_m_s))]

    def release():
        return [Segment("release", op._cmd_pos.copy(), 0.0, cfg.fine_speed_m_s, hold_steps=2)]

    def retreat():
        return [Segment("retreat", op._cmd_pos + np.array([0.0, 0.0, cfg.retreat_m]), 0.0,
                        op._speed(cfg.free_speed_m_s))]

    return [pregrasp, approach, close, lift, carry, lower, release, retreat]


PLANS: dict[str, Callable[[ScriptedOperator], list]] = {"cup_on_plate": _cup_on_plate_plan}


def make_operator(
    task: str | Task, env: TabletopEnv, rng: np.random.Generator, cfg: OperatorConfig | None = None
) -> ScriptedOperator:
    """Operator for ``task`` on a freshly reset ``env``."""
    task = get_task(task) if isinstance(task, str) else task
    return ScriptedOperator(task, env, rng, cfg)


def run_episode(env: TabletopEnv, operator: ScriptedOperator, max_steps: int = 150, obs: dict | None = None):
    """Run until ``operator.done`` or ``max_steps``; returns [(obs, action), ...]."""
    obs = env.observation() if obs is None else obs
    steps = []
    for _ in range(max_steps):
        action = operator.act(obs)
        if operator.done:
            break
        steps.append((obs, action))
        obs = env.step(action)
    return steps


def success_rate(task: str = "cup_on_plate", episodes: int = 20, twin: bool = False, seed: int = 0) -> float:
    """Fraction of scripted episodes that end in success (physics only, no rendering)."""
    from r2s_eval.sim.twin import sample_twin_params

    successes = 0
    for i in range(episodes):
        params = sample_twin_params(np.random.default_rng([seed, i, 1])) if twin else None
        env = TabletopEnv(task, params=params, cameras=())
        obs = env.reset(seed=seed * 100_000 + i)
        operator = make_operator(task, env, np.random.default_rng([seed, i, 2]))
        run_episode(env, operator, obs=obs)
        successes += env.is_success()
    return successes / episodes


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description="Success rate of the scripted teleoperator.")
    parser.add_argument("--task", default="cup_on_plate")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--twin", action="store_true", help="perturbed twin worlds instead of nominal")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rate = success_rate(args.task, args.episodes, args.twin, args.seed)
    print(f"{args.task} {'twin' if args.twin else 'nominal'}: {rate:.0%} of {args.episodes} episodes succeed")
