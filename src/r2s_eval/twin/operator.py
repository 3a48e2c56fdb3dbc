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

Plans. A task's plan is data (its ``world.tasks`` entry, ``plan``): a ``pick`` of one object followed
by one place primitive, or a ``turn_upright``. The primitives are one list (``r2s_eval.sim.plans``,
which the task check reads); each builds its segments in ``r2s_eval.twin.primitives`` from what
the operator offers there (where it commands the hand, its moves and speeds, how its hand takes
an object of a kind: ``grasp``, ``resting_centre_on`` below):

===================  ===============================================================
primitive            the operator
===================  ===============================================================
pick: X              grasps X from above (a cup round its wall near the table, a ball or
                     a block with the jaws pre-shaped just wider than it)
place_on: Y          releases it with its bottom 6 mm above Y's top face (a plate, a block)
place_in: Y          releases it 2 cm above Y's rim, over its centre: it drops in (a cup, a box)
place_over: Y        releases the upside-down object with its rim 6 mm above the table,
                     centred on Y (covering it)
put_down_beside: Y   puts it on the table beside Y (a box), towards the table's centre line (a
                     box on that line: on its side away from the arm's base)
turn_upright: X      stands the lying X (a cup) up
===================  ===============================================================

A pick and a place are one pick-and-place (``PickPlace``): pregrasp (above the
object, gripper pre-shaped) -> approach (down) -> close -> [regrasp: open, back
off, re-approach, close] -> lift -> carry (over the target, corrected for where
the object sits in the hand) -> lower -> release -> retreat. The bundled tasks:

==============  ========  ======================================================
task            grasps    releases it
==============  ========  ======================================================
cover_ball      cup       rim 6 mm above the table, centred on the ball
ball_in_box     ball      2 cm above the box rim, over the box centre (drops in)
ball_in_cup     ball      2 cm above the cup rim, over the cup (drops in)
cup_on_plate    cup       bottom 6 mm above the plate, over its centre
stack_blocks    block_a   bottom 6 mm above block_b's top face
block_from_box  block_a   on the table beside the box, towards the centre line
==============  ========  ======================================================

Heights and turns come from the arm. A top-down hand rises (to hover, carry, retreat) as high
as the settings say or as the arm reaches over the points it moves between, whichever is lower
(reach probes: IK from the commanded configuration); what a retreat cannot rise it backs off
towards the arm's base. The hand takes the yaw about the reach direction that the arm holds with
its joints nearest home (probed among quarter turns): the bundled arm's and a Panda's jaws close
across the reach, an SO-101's along it. A hand that rests far from pointing down turns down on its
way to the object.

``upright_cup`` (``turn_upright``) grasps the lying cup across its middle, lifts it, pitches the
hand by 90 deg about the jaw axis (the cup's opening turns up), lowers it onto
the table, lets go and backs off along the hand's axis. Blocks are grasped
with the jaws square to their faces; the hand turns (for round objects in
22.5 deg steps, for blocks among their face pairs) to stay close to its natural
yaw while keeping its jaws and long palm from sweeping into an
object within 15 cm or into a part of its object that stands out of its kind's footprint (the
twin's mug handle, ``r2s_eval.twin.scene``). Before closing, the operator waits until the arm has
caught up with its command (the servos lag) or has stopped short of it (a compliant arm sags).

Human-like variability (seeded by ``rng``): per-segment speed factor, short
pauses, overshoot-and-correct on free-space moves, millimetre aiming error,
and an occasional regrasp. Episodes last 6.5-10 s (65-100 control steps at 10 Hz). The
settings' step counts and per-step rates (pauses, holds, gripper rate, a segment's step limit)
are for 0.1 s steps: at a faster control rate each lasts as many control steps as make 0.1 s.

Why an episode failed: ``op.failure()`` once it is over (None when the task check holds): the phase
the operator was in when the first thing went wrong, the reason (``target_not_reached``,
``closed_on_nothing``, ``slipped``, ``joint_out_of_range``, ``out_of_time``, ``task_check_false``:
``r2s_eval.twin.failures`` says what each means) and what was seen. It only reads the scene: an
episode's actions are the same as without it.

Success rate: ``python -m r2s_eval.twin.operator --world <name> --task <key|all> --episodes 20
[--twin] [--reality JSON]`` (a world of ``conf/world`` or a world file; episodes stop after 15 s;
``--reality``: the twin's reality effects around it, e.g. its mug and rounded blocks) prints
per task the rate and the failures counted by phase and reason, then one line per failed episode.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from r2s_eval.sim.arm_ik import ArmIK, top_down_rotation
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.grasping import GraspSettings, natural_yaw, task_grasp, ticks
from r2s_eval.sim.robot import world_robot
from r2s_eval.errors import ConfigError
from r2s_eval.paths import CONF_DIR
from r2s_eval.sim.predicates import centre_m
from r2s_eval.sim.tasks import Task, get_task, world_config
from r2s_eval.twin import primitives
from r2s_eval.twin.failures import EpisodeWatch, Failure, summary
from r2s_eval.twin.perturb import sample_twin_params
from r2s_eval.twin.reality import RealityEffects, RealityEnv
from r2s_eval.twin.primitives import PlanStep, Segment


@dataclass(frozen=True)
class OperatorConfig(GraspSettings):
    """The operator's settings; those of its grasp (pre-shape, cup grasp height, gripper rate,
    closed hold, lift speed) are ``GraspSettings``', which the world check's grasp reads too."""

    free_speed_m_s: float = 0.20  # tcp speed in free space
    fine_speed_m_s: float = 0.10  # tcp speed near objects (approach, lower)
    speed_jitter_rel: float = 0.25  # per-segment speed factor U(1 -/+ jitter)
    pause_prob: float = 0.15  # chance of a pause before a segment
    pause_steps: tuple[int, int] = (1, 3)
    overshoot_prob: float = 0.3  # chance per free-space move
    overshoot_m: tuple[float, float] = (0.01, 0.025)
    aim_error_m: float = 0.003  # std of the horizontal aiming error at grasp
    regrasp_prob: float = 0.1
    hover_above_cup_m: float = 0.06  # fingertips clearance above the rim at pregrasp
    carry_tcp_height_m: float = 0.18  # tcp above the table while carrying
    place_clearance_m: float = 0.006  # cup bottom above the plate when released
    retreat_m: float = 0.10
    drop_height_m: float = 0.02  # gap under a ball released over a container
    put_down_margin_m: float = 0.03  # gap between a block put down and the box
    upright_lift_tcp_height_m: float = 0.16  # tcp above the table while turning a cup
    turn_speed_rad_s: float = 1.2  # hand rotation speed
    settle_m: float = 0.006  # before closing, wait until the real tcp is this close to the grasp pose
    neighbour_radius_m: float = 0.15  # objects this close turn the hand so its jaws miss them
    ik_iterations: int = 4
    max_steps_per_segment: int = 60


STOPPED_M_S = 0.005  # a tcp slower than this has stopped
REST_TILT_RAD = np.deg2rad(30.0)  # a hand tilted further from pointing down at the start turns gradually


class ScriptedOperator:
    """Phase machine over tcp segments; see module docstring."""

    def __init__(self, task: Task, env: TabletopEnv, rng: np.random.Generator, cfg: OperatorConfig | None = None):
        self.task, self.env, self.rng = task, env, rng
        self.cfg = cfg or OperatorConfig()
        self.done = False
        self.phase = "start"
        self._plan: list[PlanStep] = []
        self._queue: list[Segment] = []
        self._segment: Segment | None = None
        self._segment_steps = 0
        self._pause_steps = 0
        self._hold_left = 0
        self._ik: ArmIK | None = None
        self._action: np.ndarray | None = None
        self._cmd_pos: np.ndarray | None = None
        self._gripper_cmd = 0.0
        # Each step of the settings (pauses, holds, gripper rate) lasts this many control steps.
        self._ticks = ticks(env.control_dt_s)
        self.arm = self._choose_arm()
        self._watch = EpisodeWatch(env, self.arm, task.manipulated)
        self._plan = primitives.plan(self)

    # ------------------------------------------------------------ scene reads (what a person sees)
    def object_height_m(self, name: str) -> float:
        return self.task.object(name).kind_object.height_m(self.env.object_dims(name))

    def _choose_arm(self) -> str:
        arms = list(self.env.robot.arms)
        if self.task.arm in arms:
            return self.task.arm
        if self.task.arm not in ("nearest", "behind_axis"):
            raise ConfigError(f"world.tasks.{self.task.key}.arm: {self.task.arm!r} is not an arm of the robot {arms}")
        bases = self.env.arm_base_positions()
        if self.task.arm == "behind_axis":  # the arm from whose side the object's axis points away
            name = self.task.manipulated
            yaw = self.env.object_poses()[name]["yaw_rad"]
            axis = np.array([np.cos(yaw), np.sin(yaw)])
            xy = centre_m(self.env, name)[:2]

            def alignment(arm):
                reach = xy - bases[arm][:2]
                return float(axis @ reach / np.linalg.norm(reach))

            return max(arms, key=alignment)
        mid_y = np.mean([centre_m(self.env, n)[1] for n in self.task.object_names])
        return min(arms, key=lambda a: abs(bases[a][1] - mid_y))

    def _grasp_yaw(self) -> float:
        """Approach yaw of the top-down hand (its jaws close across it).

        At the arm's natural yaw for round objects, square to a block's or box's faces; and, like a
        person, turned so the jaws and the long palm do not sweep into a close neighbour or a part
        of the object that stands out (a mug's handle).
        """
        name = self.task.manipulated
        centre = centre_m(self.env, name)
        xy = centre[:2]
        reach = xy - self.env.arm_base_positions()[self.arm][:2]
        obj_yaw = self.env.object_poses()[name]["yaw_rad"]
        if self.task.placement(name) == "on_side":
            return obj_yaw  # jaws across the lying axis; the hand's z axis along it
        natural = natural_yaw(self._ik, centre, float(np.arctan2(reach[1], reach[0])))
        base, step = self.task.object(name).kind_object.grasp_yaws(obj_yaw, natural)
        candidates = base + step * np.arange(-int(np.pi / step), int(np.pi / step) + 1)
        others = [centre_m(self.env, n)[:2] - xy for n in self.task.object_names if n != name]
        near = [d / np.linalg.norm(d) for d in others if np.linalg.norm(d) < self.cfg.neighbour_radius_m]
        near += self._protrusion(name, xy)

        def cost(yaw: float) -> float:
            turn = abs(np.angle(np.exp(1j * (yaw - natural))))
            jaw_axis = np.array([-np.sin(yaw), np.cos(yaw)])
            return turn + sum(2.0 * abs(float(jaw_axis @ d)) for d in near)

        return float(min(candidates, key=cost))

    def _protrusion(self, name: str, xy: np.ndarray) -> list[np.ndarray]:
        """The direction on the table in which parts of ``name`` stand out beyond its kind's
        footprint (a mug's handle, which the twin's cup may have and the world's cup has not),
        kept out of the jaws' way as a close neighbour is; [] for an object within its footprint."""
        model, data = self.env.model, self.env.data
        radius = self.task.object(name).kind_object.footprint_radius_m(self.env.object_dims(name),
                                                                        self.task.placement(name))
        offsets = data.geom_xpos[model.geom_bodyid == model.body(name).id][:, :2] - xy
        outside = offsets[np.linalg.norm(offsets, axis=1) > radius]
        if not len(outside):
            return []
        direction = outside.sum(axis=0)
        return [direction / np.linalg.norm(direction)] if np.linalg.norm(direction) > 0 else []

    def reachable_z(self, xys, z: float) -> float:
        """``z``, or the highest height below it that the hand (in its grasp orientation) reaches
        over every point of ``xys``."""
        return min(self._ik.highest_z(np.asarray(xy), self.env.table_top_z_m, z, self._R_grasp) for xy in xys)

    # ------------------------------------------------------------ what the plan primitives use
    @property
    def cmd_pos(self) -> np.ndarray:
        """The commanded tcp position (world)."""
        return self._cmd_pos

    @property
    def R_cmd(self) -> np.ndarray:
        """The commanded hand orientation (world)."""
        return self._R_cmd

    def grasp(self, name: str) -> tuple[Callable[[ScriptedOperator], float], float]:
        """How the hand takes ``name`` from above: the tcp height when closing, and the pre-shape."""
        return _grasp(self, name)

    def resting_centre_on(self, held: str, support: str) -> Callable[[ScriptedOperator], np.ndarray]:
        """Where the held object's centre is released onto ``support`` (a function of the scene)."""
        return _place_on(self, held, support)

    def do_next(self, steps: list[PlanStep]) -> None:
        """Do these plan steps before the rest of the plan (a regrasp)."""
        self._plan[:0] = steps

    def aim(self) -> np.ndarray:
        """A horizontal aiming error (m), as a person's hand misses by millimetres."""
        return self.rng.normal(0.0, self.cfg.aim_error_m, 2)

    def speed(self, base_m_s: float) -> float:
        j = self.cfg.speed_jitter_rel
        return base_m_s * self.rng.uniform(1.0 - j, 1.0 + j)

    def free_move(self, name: str, pos_world_m: np.ndarray, gripper: float) -> list[Segment]:
        """A free-space move, sometimes overshooting horizontally and correcting; the hand turns to
        its grasp orientation on the way if it is not there yet."""
        turn = None if np.array_equal(self._R_cmd, self._R_grasp) else self._R_grasp
        speed = self.cfg.free_speed_m_s
        segments = []
        if self.rng.random() < self.cfg.overshoot_prob and self._cmd_pos is not None:
            direction = pos_world_m - self._cmd_pos
            direction[2] = 0.0
            norm = np.linalg.norm(direction)
            if norm > 0.03:
                over = pos_world_m + direction / norm * self.rng.uniform(*self.cfg.overshoot_m)
                segments.append(Segment(f"{name}_overshoot", over, gripper, self.speed(speed), R_world=turn))
        segments.append(Segment(name, pos_world_m, gripper, self.speed(speed), R_world=turn))
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
        robot = self.env.robot
        measured = robot.to_model(state)
        self._ik = ArmIK(robot, self.arm, {name: q for name, (q, _) in measured.items()})
        self._cmd_pos, _ = self._ik.tcp_pose()
        self._ee = self.env.ee_positions()[self.arm]  # the real tcp, as last seen
        self._R_grasp = top_down_rotation(self._grasp_yaw())
        # A hand that rests far from pointing down (a small arm's folded rest) turns down on the
        # way to the object, at the turn speed, not in one step.
        _, hand = self._ik.tcp_pose()
        self._R_cmd = hand if -hand[2, 0] < np.cos(REST_TILT_RAD) else self._R_grasp
        # Commands per arm in model units (joint targets, gripper closing): the others held at home
        # with their grippers open, the operator's arm from where it is. A person at the controls
        # sees where the gripper really is and aims accordingly: the commands make up for the
        # arm's joint offsets, so the recorded joint targets are off by them (what action replay
        # in a nominal simulation then has to absorb).
        self._joint_offsets = self.env.params.joint_offsets(self.arm, len(robot.arms[self.arm].joints))
        self._command = robot.home_targets()
        self._command[self.arm] = (measured[self.arm][0] - self._joint_offsets, 0.0)
        self._action = robot.from_model(self._command)

    def _next_segment(self) -> bool:
        while not self._queue:
            if not self._plan:
                return False
            self._queue = self._plan.pop(0)()
        self._segment = self._queue.pop(0)
        self.phase = self._segment.name
        self._watch.segment_started(self._segment.name, self._segment.gripper)
        self._segment_steps = 0
        self._hold_left = self._segment.hold_steps * self._ticks
        if self.rng.random() < self.cfg.pause_prob:
            steps = int(self.rng.integers(self.cfg.pause_steps[0], self.cfg.pause_steps[1] + 1))
            self._pause_steps = steps * self._ticks
        return True

    def _advance(self) -> None:
        ee_before, self._ee = self._ee, self.env.ee_positions()[self.arm]
        self._watch.step(self.phase)
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
        max_step = seg.speed_m_s * self.env.control_dt_s
        self._cmd_pos = seg.pos_world_m.copy() if dist <= max_step else self._cmd_pos + delta / dist * max_step
        turned = True
        if seg.R_world is not None:
            rotvec = Rotation.from_matrix(seg.R_world @ self._R_cmd.T).as_rotvec()
            angle = float(np.linalg.norm(rotvec))
            max_turn = self.cfg.turn_speed_rad_s * self.env.control_dt_s
            if angle > max_turn:
                rotvec *= max_turn / angle
                turned = False
            self._R_cmd = Rotation.from_rotvec(rotvec).as_matrix() @ self._R_cmd
        rate = self.cfg.gripper_rate_per_step / self._ticks
        self._gripper_cmd += float(np.clip(seg.gripper - self._gripper_cmd, -rate, rate))
        self._command[self.arm] = (self._ik.solve(self._cmd_pos, self._R_cmd, self.cfg.ik_iterations)
                                   - self._joint_offsets, self._gripper_cmd)
        self._action = self.env.robot.from_model(self._command)
        arrived = dist <= max_step and turned and abs(seg.gripper - self._gripper_cmd) < 1e-9
        if arrived and seg.settle_m is not None:
            # The arm lags its command: wait until it is there, or has stopped short of it (a
            # compliant arm sags under its own weight).
            arrived = (float(np.linalg.norm(self._ee - self._cmd_pos)) <= seg.settle_m
                       or float(np.linalg.norm(self._ee - ee_before)) < STOPPED_M_S * self.env.control_dt_s)
        if arrived:
            if self._hold_left > 0:
                self._hold_left -= 1
            else:
                self._segment = None
                self._watch.segment_ended(seg.name, seg.pos_world_m, gave_up=False, check_reach=seg.settle_m is not None)
        elif self._segment_steps > self.cfg.max_steps_per_segment * self._ticks:
            self._segment = None  # give up on an unreachable target
            self._watch.segment_ended(seg.name, seg.pos_world_m, gave_up=True, check_reach=True)

    def failure(self) -> Failure | None:
        """Why the episode failed, once it is over (None: its task check holds): the first thing
        that went wrong and the phase it went wrong in (``r2s_eval.twin.failures``)."""
        return self._watch.failure(self.phase, self.done, self.env.steps)


# ---------------------------------------------------------------- how the hand takes an object
def _grasp(op: ScriptedOperator, name: str) -> tuple[Callable[[ScriptedOperator], float], float]:
    """How the hand takes ``name`` from above (``r2s_eval.sim.grasping``, which the world check's
    grasp reads too): the tcp height when closing, and the pre-shape."""
    env = op.env
    grasp = task_grasp(op.task, name, env.object_dims(name), env.robot.arms[op.arm].gripper.jaw_open_m, op.cfg)
    return (lambda op: grasp.tcp_z_m(centre_m(op.env, name)[2], op.env.table_top_z_m)), grasp.preshape


def _place_on(op: ScriptedOperator, held: str, support: str) -> Callable[[ScriptedOperator], np.ndarray]:
    """The held object's bottom a little above the support's top face, over its centre."""
    env, cfg = op.env, op.cfg
    kind, dims, held_h = op.task.object(support).kind_object, env.object_dims(support), op.object_height_m(held)

    def place(op):
        pos = env.object_state(support)["pos_world_m"]
        return np.r_[pos[:2], pos[2] + kind.support_top_m(dims) + cfg.place_clearance_m + held_h / 2]

    return place


def make_operator(
    task: str | Task, env: TabletopEnv, rng: np.random.Generator, cfg: OperatorConfig | None = None
) -> ScriptedOperator:
    """Operator for ``task`` (the env's own, when named by its key) on a freshly reset ``env``."""
    if isinstance(task, str):
        if task != env.task.key:
            raise ValueError(f"operator for task {task!r} on an environment of task {env.task.key!r}")
        task = env.task
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


# The success rate's episodes stop after the teleop stage's time (its config group's default: one owner).
EPISODE_S = float(yaml.safe_load((CONF_DIR / "teleop" / "default.yaml").read_text())["max_duration_s"])


def episode_failures(task: str, episodes: int = 20, twin: bool = False, seed: int = 0, *,
                     world: dict, reality: RealityEffects | None = None) -> list[Failure | None]:
    """Why each scripted episode failed (None: it succeeded; physics only, no rendering) in ``world``
    (a ``world`` config slice); ``reality``: the twin's reality effects around it (its servos, its
    objects' true shapes), None: none."""
    robot, spec = world_robot(world), get_task(task, world)
    failures = []
    for i in range(episodes):
        params = (sample_twin_params(np.random.default_rng([seed, i, 1]), object_names=spec.object_names, robot=robot)
                  if twin else None)
        env = (TabletopEnv(spec, params=params, cameras=(), robot=robot) if reality is None
               else RealityEnv(spec, params, reality, cameras=(), robot=robot))
        obs = env.reset(seed=seed * 100_000 + i)
        operator = make_operator(spec, env, np.random.default_rng([seed, i, 2]))
        run_episode(env, operator, robot.steps_in(EPISODE_S), obs=obs)
        failures.append(operator.failure())
        env.close()
    return failures


def success_rate(task: str, episodes: int = 20, twin: bool = False, seed: int = 0, *, world: dict) -> float:
    """Fraction of scripted episodes that end in success (``episode_failures``)."""
    return sum(f is None for f in episode_failures(task, episodes, twin, seed, world=world)) / episodes


if __name__ == "__main__":
    import argparse
    import json

    parser = argparse.ArgumentParser(description="Success rate of the scripted teleoperator, and why episodes fail.")
    parser.add_argument("--world", required=True, help="a world of conf/world (tabletop, panda, ...) or a world file")
    parser.add_argument("--task", default="all", help="task key, or 'all'")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--twin", action="store_true", help="perturbed twin worlds instead of nominal")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reality", help="the twin's reality effects as JSON (RealityEffects' fields), e.g. "
                                          "'{\"cup_handle\": true, \"block_edge_radius_m\": 0.004}'")
    args = parser.parse_args()
    world_cfg = world_config(args.world)
    reality = None if args.reality is None else RealityEffects.from_dict(json.loads(args.reality))
    for key in world_cfg["tasks"] if args.task == "all" else [args.task]:
        failures = episode_failures(key, args.episodes, args.twin, args.seed, world=world_cfg, reality=reality)
        rate, why = sum(f is None for f in failures) / args.episodes, summary(failures)
        print(f"{key} {'twin' if args.twin else 'nominal'}: {rate:.0%} of {args.episodes} episodes succeed"
              + (f"; failed: {why}" if why else ""), flush=True)
        for i, failure in enumerate(failures):
            if failure is not None:
                print(f"  episode {i}: {failure}", flush=True)
