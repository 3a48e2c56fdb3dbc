"""The typed world spec (r2s_eval.sim.world_spec): every problem of a world listed at once with its
key (and, in a composed configuration, its file), defaults from the spec, and the keys for robots
as their makers ship them read into the runtime fields."""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import pytest

from r2s_eval.config import compose_config
from r2s_eval.errors import ConfigError
from r2s_eval.sim.robot import load_robot
from r2s_eval.sim.tasks import WorldError, load_tasks
from tests.helpers.worlds import bundled_world

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_a_world_with_several_problems_lists_them_all_with_their_file(tmp_path):
    conf = Path(shutil.copytree(CONF, tmp_path / "conf"))
    world = conf / "world" / "tabletop.yaml"
    text = world.read_text().replace("control_hz: 10", "control_hz: -10").replace("mass_kg: 0.25", "mass_kg: zero")
    world.write_text(text.replace("ee: {site: tcp, approach: +x, jaw: +y}\n    right:",
                                  "ee: {site: tcp, approach: +x, jaw: -x}\n    right:"))
    with pytest.raises(ConfigError) as err:
        compose_config(conf, "smoke")
    lines = str(err.value).splitlines()
    assert lines[0] == "3 configuration problems:", str(err.value)
    assert set(lines[1:]) == {
        "  - world.robot.control_hz (set in conf/world/tabletop.yaml) must be in (0, inf], got -10",
        "  - world.robot.arms.left.ee (set in conf/world/tabletop.yaml) approach and jaw must be different axes, "
        "got +x and -x",
        "  - world.objects.plate.mass_kg (set in conf/world/tabletop.yaml) must be a number, got 'zero' (str)"}


def test_the_robot_read_outside_a_config_lists_every_problem():
    world = copy.deepcopy(bundled_world())
    left = world["robot"]["arms"]["left"]
    left["gripper"] = {**left["gripper"], "ctrl": {"open": 0.05, "closed": 0.05}}  # the right arm's stays
    world["robot"]["arms"]["right"]["home"] = [0.0]
    world["rig"]["wrist_left"]["arm"] = "middle"
    with pytest.raises(WorldError) as err:
        load_robot(world)
    assert str(err.value).splitlines() == [
        "3 world problems:",
        "  - world.robot.arms.left.gripper.ctrl: open and closed must differ, got 0.05 for both",
        "  - world.robot.arms.right.home: must be a list of 6 numbers (one per joint), got [0.0]",
        "  - world.rig.wrist_left.arm: must be an arm of the robot ['left', 'right'], got 'middle'"]


def test_tasks_with_problems_are_listed_together():
    world = copy.deepcopy(bundled_world())
    world["tasks"]["cup_on_plate"]["plan"] = [{"pick": "cup"}, {"drop": "plate"}]
    world["tasks"]["ball_in_box"]["start"]["ball"]["relative_to"] = "ball"
    with pytest.raises(WorldError) as err:
        load_tasks(world)
    assert [p for p, _ in err.value.problems] == ["world.tasks.ball_in_box.start.ball.relative_to",
                                                  "world.tasks.cup_on_plate.plan[1]"]


def test_defaults_come_from_the_spec():
    robot = load_robot(bundled_world())
    arm = robot.arms["left"]
    assert arm.actuators == arm.joints and arm.servo is None and not arm.gravity_compensation
    assert arm.ee_pos == (0.0, 0.0, 0.0) and robot.timestep_s is None and robot.type == "r2s_dual_arm"
    assert arm.model_body is None and arm.model_assets == () and arm.joint_physics is None
    assert arm.gripper.fingers == () and arm.gripper.couple == () and arm.gripper.servo is None
    task = load_tasks(bundled_world())["cup_on_plate"]
    assert task.arm == "nearest" and task.clearance_m == 0.03


def test_the_keys_for_robots_as_their_makers_ship_them_reach_the_runtime_fields():
    world = copy.deepcopy(bundled_world())
    left = world["robot"]["arms"]["left"]
    left["model"] = {"path": "assets/arm.xml", "body": "base", "assets": [{"path": "assets/tabletop.xml"}]}
    left["physics"] = {"joints": {"armature": 0.1, "damping": 1.0}, "fingers": {"frictionloss": 0.2}}
    left["gripper"] = {**left["gripper"], "joint": "finger_a", "servo": {"kp": 200, "kv": 10},
                       "couple": [{"joint": "finger_b", "ratio": 1.0}]}
    world["robot"]["arms"]["right"]["gripper"] = {
        **left["gripper"], "couple": [],
        "fingers": [{"joint": "finger_b", "actuator": "finger_b", "ctrl": {"open": 0.05, "closed": 0.0},
                     "position": {"open": 0.05, "closed": 0.0}}]}
    robot = load_robot(world)
    arm = robot.arms["left"]
    assert arm.model.name == "arm.xml" and arm.model_body == "base" and arm.model_assets[0].name == "tabletop.xml"
    assert (arm.joint_physics.armature, arm.joint_physics.damping, arm.joint_physics.frictionloss) == (0.1, 1.0, None)
    assert arm.finger_physics.frictionloss == 0.2
    assert arm.gripper.couple == (("finger_b", 1.0),) and arm.gripper.servo == (200.0, 10.0)
    finger = robot.arms["right"].gripper.fingers[0]
    assert (finger.joint, finger.actuator, finger.ctrl_open, finger.position_closed) == ("finger_b", "finger_b", 0.05, 0.0)


def test_a_body_subtree_needs_a_file_reference():
    world = copy.deepcopy(bundled_world())
    world["robot"]["arms"]["left"]["model"] = {"body": "base"}
    with pytest.raises(WorldError, match=r"^world\.robot\.arms\.left\.model: must give path, or package and resource$"):
        load_robot(world)


def test_an_objects_dimensions_are_its_kinds():
    world = copy.deepcopy(bundled_world())
    world["objects"]["cup"]["dims"]["radius"] = world["objects"]["cup"]["dims"].pop("radius_m")
    world["objects"]["block_a"]["dims"]["height_m"] = 0.05
    with pytest.raises(WorldError) as err:
        load_tasks(world)
    assert str(err.value).splitlines()[1:] == [
        "  - world.objects.cup.dims.radius: is not a dimension of a cup "
        "['radius_m', 'height_m', 'wall_m', 'bottom_m', 'n_walls', 'base_radius_m', 'handle_low_m', "
        "'handle_high_m', 'handle_out_m', 'handle_thickness_m']",
        "  - world.objects.cup.dims.radius_m: is missing",
        "  - world.objects.block_a.dims.height_m: is not a dimension of a block ['size_m', 'edge_radius_m']"]


def test_a_mugs_handle_takes_all_its_dimensions_and_fits_on_the_cup():
    world = copy.deepcopy(bundled_world())
    world["objects"]["cup"]["dims"].update(handle_low_m=0.021, handle_high_m=0.09, handle_out_m=0.025)
    with pytest.raises(WorldError) as err:
        load_tasks(world)
    assert str(err.value) == ("world.objects.cup.dims.handle_thickness_m: is missing: a mug's handle takes all of "
                              "['handle_low_m', 'handle_high_m', 'handle_out_m', 'handle_thickness_m']")
    world["objects"]["cup"]["dims"].update(handle_thickness_m=0.03)
    with pytest.raises(WorldError) as err:
        load_tasks(world)
    assert [line.split(":")[0] for line in str(err.value).splitlines()[1:]] == [
        "  - world.objects.cup.dims.handle_high_m", "  - world.objects.cup.dims.handle_out_m"]
    world["objects"]["cup"]["dims"].update(handle_high_m=0.068, handle_thickness_m=0.009)
    world["objects"]["block_a"]["dims"]["edge_radius_m"] = 0.03
    with pytest.raises(WorldError) as err:
        load_tasks(world)
    assert str(err.value) == "world.objects.block_a.dims.edge_radius_m: must lie between 0 and half the edge size_m " \
                             "(0.0225), got 0.03"
