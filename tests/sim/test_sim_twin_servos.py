"""The twin's servos (``r2s_eval.twin.servos``, applied by ``RealityEnv``): late by a latency in
seconds (a fraction of a control step switches the command mid-period), with play in the arm
joints (backlash) and with a gripper that gives under load; with every effect off, the simulated
servos' bytes."""

import numpy as np
import pytest

from r2s_eval.errors import ConfigError, PolicyError
from r2s_eval.sim import WorldParams
from r2s_eval.twin.reality import RealityEffects
from r2s_eval.twin.servos import LatePipeline, delay_substeps
from tests.helpers.commands import POSES, run, wandering_commands
from tests.helpers.worlds import bundled_env, bundled_twin_env

ARM = "right"


# ----------------------------------------------------------------------------- latency


def test_the_pipeline_splits_a_latency_into_whole_periods_and_an_arrival_within_one():
    assert delay_substeps(0.15, 0.002) == 75
    pipeline = LatePipeline(75, 50)  # one period and 25 physics steps
    assert (pipeline.periods, pipeline.arrival_substep) == (1, 25)
    commands = [np.full(2, float(k)) for k in range(4)]
    assert pipeline.send(commands[0]) is None  # nothing arrives in the first period
    assert [pipeline.send(c)[0] for c in commands[1:]] == [0.0, 1.0, 2.0]  # then each one period and 25 steps late
    pipeline.clear()
    assert pipeline.send(commands[0]) is None


def test_a_whole_step_latency_in_seconds_answers_as_the_sims_whole_step_answer():
    """The twin late by one control period (0.1 s) steps what the calibrated sim's answer of one
    step steps: the same targets and the same physics, byte for byte."""
    twin = bundled_twin_env("cup_on_plate", reality=RealityEffects(latency_s=0.1), cameras=())
    answer = bundled_env("cup_on_plate", WorldParams(command_latency_steps=1), cameras=())
    commands = wandering_commands(answer, 12, seed=1)
    twin_targets, twin_joints = run(twin, commands)
    answer_targets, answer_joints = run(answer, commands)
    assert np.array_equal(twin_targets, answer_targets) and np.array_equal(twin_joints, answer_joints)
    for env in (twin, answer):
        env.close()


def test_a_latency_between_steps_switches_the_command_mid_period():
    """0.15 s at 10 Hz: each command arrives 25 of 50 physics steps into the period after the one
    it was sent in, so the targets at the period's end are the one-step answer's and the arm's
    path runs between the one-step and the two-step answers'."""
    twin = bundled_twin_env("cup_on_plate", reality=RealityEffects(latency_s=0.15), cameras=())
    one, two = (bundled_env("cup_on_plate", WorldParams(command_latency_steps=k), cameras=()) for k in (1, 2))
    commands = wandering_commands(one, 12, seed=2)
    twin.reset(POSES, seed=0, observe=False)
    at_reset = twin.data.ctrl.copy()
    twin_targets, twin_joints = run(twin, commands)
    one_targets, one_joints = run(one, commands)
    _, two_joints = run(two, commands)
    assert np.array_equal(twin_targets, one_targets)
    assert np.array_equal(twin_targets[0], at_reset)  # until the first command arrives: the reset targets
    arm_joints = [twin.model.joint(twin.robot.arms[ARM].named(j)).qposadr[0] for j in twin.robot.arms[ARM].joints]
    gap = np.abs(one_joints - two_joints)[:, arm_joints].sum()
    assert np.abs(twin_joints - one_joints)[:, arm_joints].sum() < 0.8 * gap
    assert np.abs(twin_joints - two_joints)[:, arm_joints].sum() < 0.8 * gap
    # A new episode starts with nothing under way: the last episode's commands never arrive.
    twin.reset(POSES, seed=0, observe=False)
    twin.step(commands[0], images=False)
    assert np.array_equal(twin.data.ctrl, at_reset)
    # A command that is no number is refused when it is sent, not when it would arrive.
    bad = commands[1].copy()
    bad[3] = np.nan
    with pytest.raises(PolicyError, match="non-finite"):
        twin.step(bad, images=False)
    for env in (twin, one, two):
        env.close()


def test_a_twin_is_late_by_its_own_latency_or_by_the_sims_answer_never_both():
    with pytest.raises(ConfigError, match="late by its own latency_s .* and by command_latency_steps"):
        bundled_twin_env("cup_on_plate", WorldParams(command_latency_steps=1), RealityEffects(latency_s=0.1),
                         cameras=())
    with pytest.raises(ConfigError, match="latency_s must be >= 0"):
        bundled_twin_env("cup_on_plate", reality=RealityEffects(latency_s=-0.1), cameras=())


# ----------------------------------------------------------------------------- backlash


def test_backlash_holds_the_joint_within_its_play_and_trails_by_half_the_band_beyond():
    band = float(np.deg2rad(2.0))
    env = bundled_twin_env("cup_on_plate", reality=RealityEffects(backlash_rad=band), cameras=())
    env.reset(POSES, seed=0, observe=False)
    arm = env.robot.arms[ARM]
    j1 = env.model.actuator(arm.named(arm.actuators[0])).id  # base yaw: no gravity load to sag under
    j1_qpos = env.model.joint(arm.named(arm.joints[0])).qposadr[0]
    home = env.robot.home_targets()
    command = {name: (q.copy(), closing) for name, (q, closing) in home.items()}
    start = float(home[ARM][0][0])

    def hold(yaw_rad: float, steps: int = 12) -> tuple[float, float]:
        command[ARM][0][0] = yaw_rad
        for _ in range(steps):
            env.step(env.robot.from_model(command), images=False)
        return float(env.data.ctrl[j1]), float(env.data.qpos[j1_qpos])

    peak = start + np.deg2rad(4.0)
    target, joint = hold(peak)
    assert target == pytest.approx(peak - band / 2, abs=1e-12)  # dragged along, half the band behind
    assert joint == pytest.approx(target, abs=2e-4)
    # Back by less than the band: the play is taken up on the other side, the joint stays put.
    target_within, joint_within = hold(peak - 0.75 * band)
    assert target_within == target and joint_within == pytest.approx(joint, abs=1e-4)  # still settling: 3e-5
    # Back beyond it: the joint follows again, now half the band above the command.
    low = peak - np.deg2rad(4.0)
    target_beyond, joint_beyond = hold(low)
    assert target_beyond == pytest.approx(low + band / 2, abs=1e-12)
    assert joint_beyond == pytest.approx(target_beyond, abs=2e-4)
    # A reset takes the play up around the reset targets again.
    env.reset(POSES, seed=0, observe=False)
    command[ARM][0][0] = start + 0.4 * band
    env.step(env.robot.from_model(command), images=False)
    assert env.data.ctrl[j1] == start
    env.close()


def test_a_late_command_moves_through_the_play_when_it_arrives():
    band = float(np.deg2rad(2.0))
    env = bundled_twin_env("cup_on_plate", reality=RealityEffects(latency_s=0.1, backlash_rad=band), cameras=())
    env.reset(POSES, seed=0, observe=False)
    arm = env.robot.arms[ARM]
    j1 = env.model.actuator(arm.named(arm.actuators[0])).id
    command = {name: (q.copy(), closing) for name, (q, closing) in env.robot.home_targets().items()}
    start = float(command[ARM][0][0])
    command[ARM][0][0] = start + np.deg2rad(3.0)
    env.step(env.robot.from_model(command), images=False)
    assert env.data.ctrl[j1] == start  # not there yet
    env.step(env.robot.from_model(command), images=False)
    assert env.data.ctrl[j1] == pytest.approx(start + np.deg2rad(3.0) - band / 2, abs=1e-12)
    env.close()


# ----------------------------------------------------------------------------- gripper


def squeezed_ball(strength: float, load_n: float) -> tuple[float, str | None]:
    """The right gripper closed on the ball (gravity off: the load is all there is), then the ball
    pushed along the jaws' closing axis with ``load_n``: the measured gripper closing (0 open ..
    1 closed) and whether the gripper still holds the ball."""
    env = bundled_twin_env("ball_in_cup", reality=RealityEffects(gripper_strength_scale=strength), cameras=())
    env.model.opt.gravity[:] = 0.0
    env.reset({"ball": (0.0, 0.1, 0.0), "cup": (-0.1, -0.12, 0.0)}, seed=0, observe=False)
    env.set_object_pose("ball", env.ee_positions()[ARM] - [0.0, 0.0, env.object_dims("ball")["radius_m"]])
    close = env.robot.from_model({name: (q, 1.0 if name == ARM else 0.0)
                                  for name, (q, _) in env.robot.home_targets().items()})
    for _ in range(10):
        env.step(close, images=False)
    ball, jaw_axis = env.model.body("ball").id, env.ee_rotations()[ARM][:, 1]
    for share in np.linspace(0.1, 1.0, 10):  # the load builds up over a second
        env.data.xfrc_applied[ball, :3] = share * load_n * jaw_axis
        env.step(close, images=False)
    for _ in range(10):
        env.step(close, images=False)
    _, gripper = env.robot.slices(ARM)
    closing, held = float(env.state()[gripper]), env.grasped("ball")
    env.close()
    return closing, held


def test_a_weaker_gripper_gives_under_a_load_that_the_nominal_one_holds():
    """Half strength (LeRobot's SO-100/SO-101 follower caps its gripper at 50 % torque): under
    the same 5 N push the jaws open further than the nominal ones; a 7 N push, which the nominal
    gripper holds, pushes the ball out of the weak one (its squeeze, about 6 N, gives way)."""
    nominal_closing, nominal_held = squeezed_ball(1.0, 5.0)
    weak_closing, weak_held = squeezed_ball(0.5, 5.0)
    assert nominal_held == weak_held == ARM
    assert weak_closing < nominal_closing - 0.005  # further open (0.61 against 0.62 measured)
    assert squeezed_ball(1.0, 7.0)[1] == ARM
    assert squeezed_ball(0.5, 7.0)[1] is None


def test_the_gripper_scale_touches_only_the_gripper_servos_of_the_twins_own_model():
    nominal = bundled_env("cup_on_plate", cameras=())
    weak = bundled_twin_env("cup_on_plate", reality=RealityEffects(gripper_strength_scale=0.5), cameras=())
    grippers = [nominal.model.actuator(arm.named(arm.gripper.actuator)).id for arm in nominal.robot.arms.values()]
    others = [i for i in range(nominal.model.nu) if i not in grippers]
    for name in ("actuator_gainprm", "actuator_biasprm", "actuator_forcerange"):
        a, b = getattr(nominal.model, name), getattr(weak.model, name)
        assert np.array_equal(a[others], b[others])
    assert np.allclose(weak.model.actuator_gainprm[grippers, 0], 0.5 * nominal.model.actuator_gainprm[grippers, 0])
    assert np.allclose(weak.model.actuator_forcerange[grippers], 0.5 * nominal.model.actuator_forcerange[grippers])
    # A second environment sharing the twin's compiled model (as the rollout pool shares it) does
    # not weaken it again.
    shared = bundled_twin_env("cup_on_plate", reality=RealityEffects(gripper_strength_scale=0.5), cameras=(),
                              model=weak.model)
    assert np.allclose(shared.model.actuator_gainprm[grippers, 0], 0.5 * nominal.model.actuator_gainprm[grippers, 0])
    for env in (nominal, weak, shared):
        env.close()
