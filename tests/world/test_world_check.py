"""The physical world check (r2s_eval.sim.world_check) and the camera settings a world decides."""

from __future__ import annotations

import os

import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from r2s_eval.config import compose_config  # noqa: E402
from r2s_eval.errors import ConfigError  # noqa: E402
from r2s_eval.paths import CONF_DIR, REPO_ROOT  # noqa: E402
from r2s_eval.sim.grasping import GraspSettings, grasp_settings  # noqa: E402
from r2s_eval.sim.world_check import check_world, world_problems  # noqa: E402
from r2s_eval.twin.operator import OperatorConfig  # noqa: E402


def _bundled(*tasks: str) -> dict:
    world = yaml.safe_load((CONF_DIR / "world" / "tabletop.yaml").read_text())
    if tasks:
        world["tasks"] = {key: world["tasks"][key] for key in tasks}
    return world


def test_the_bundled_world_passes():
    assert world_problems(_bundled()) == []


def test_fingers_flung_past_their_limits_at_home_are_named(tmp_path):
    # The bundled arm with a gripper servo 30 times as stiff and 60 times as strong, on undamped
    # fingers without armature: closing at home, the fingers shoot through their lower limit.
    arm = (REPO_ROOT / "assets" / "arm.xml").read_text()
    stiff = arm.replace('damping="2" armature="0.01" frictionloss="0"', 'damping="0" armature="0" frictionloss="0"')
    stiff = stiff.replace('kp="600" kv="20" ctrlrange="0 0.05"\n              forcerange="-30 30"',
                          'kp="20000" kv="0" ctrlrange="0 0.05"\n              forcerange="-2000 2000"')
    assert stiff.count('kp="20000"') == 1 and 'armature="0" ' in stiff
    (tmp_path / "arm.xml").write_text(stiff)
    world = _bundled("stack_blocks")
    world["robot"]["arms"]["left"]["model"] = str(tmp_path / "arm.xml")
    lines = world_problems(world)
    assert lines[0].startswith("world.robot.arms.left.gripper: finger_a reached -0.05")
    assert lines[0].endswith("at home with the gripper closed, range 0..0.05")
    assert lines[1].startswith("world.robot.arms.left.gripper: finger_b reached -0.0")  # its coupled twin
    assert not any(line.startswith("world.robot.arms.right") for line in lines)  # the right arm is the bundled one
    with pytest.raises(ConfigError, match=r"physical problems of the world:\n  - world.robot.arms.left.gripper"):
        check_world(world)


def test_a_gripper_that_does_not_hold_its_object_is_named():
    # A 5 kg block: the bundled gripper closes on it, but it stays on the table when the hand rises.
    world = _bundled("stack_blocks")
    world["objects"]["block_a"]["mass_kg"] = 5.0
    world["tasks"]["stack_blocks"]["arm"] = "right"
    lines = world_problems(world)
    assert len(lines) == 1
    assert lines[0].startswith("world.robot.arms.right.gripper: did not hold block_a: it stayed 4.")
    assert lines[0].endswith("cm lift")
    with pytest.raises(ConfigError, match=r"^world.robot.arms.right.gripper: did not hold block_a"):
        check_world(world)


def test_the_check_grasps_with_the_operators_settings():
    # One owner: the operator's grasp settings are GraspSettings' fields, defaults included; the
    # check takes those of a teleop.operator entry (the rest are the operator's alone).
    assert issubclass(OperatorConfig, GraspSettings)
    assert GraspSettings(**{k: getattr(OperatorConfig(), k) for k in vars(GraspSettings())}) == GraspSettings()
    assert grasp_settings({"lift_speed_m_s": 0.3, "free_speed_m_s": 0.5}) == GraspSettings(lift_speed_m_s=0.3)
    assert grasp_settings(None) == GraspSettings()


def test_cameras_follow_the_world():
    # The bundled world's settings are what they were (head_left); the Panda's first recorded fixed
    # camera when the experiment leaves them to the world.
    smoke = compose_config(CONF_DIR, "smoke")
    assert smoke["calib"]["camera"] == smoke["rollout"]["video_camera"] == "head_left"
    trained = [p for p in smoke["policies"].values() if p["type"] == "act"]
    assert {tuple(p["image_keys"]) for p in trained} == {("observation.images.head_left",)}
    panda = compose_config(CONF_DIR, "smoke", ["world=panda", "suite=world", "tasks=[block_on_plate]",
                                               "world.cameras=[wrist,front]"])
    assert panda["calib"]["camera"] == panda["rollout"]["video_camera"] == "front"
    trained = [p for p in panda["policies"].values() if p["type"] == "act"]
    assert {tuple(p["image_keys"]) for p in trained} == {("observation.images.front",)}


def test_a_world_without_a_fixed_camera_says_which_setting_to_give():
    with pytest.raises(ConfigError) as err:
        compose_config(CONF_DIR, "smoke", ["world.cameras=[wrist_left]"])
    assert str(err.value) == (
        "calib.camera (set in conf/calib/default.yaml) is null (the world's first recorded fixed camera), but "
        "world.cameras ['wrist_left'] records none (a camera on no arm); set calib.camera, rollout.video_camera, "
        "policies.act.image_keys, policies.act_subset.image_keys, policies.act_weak.image_keys")
    given = compose_config(CONF_DIR, "smoke", ["world.cameras=[wrist_left]", "calib.camera=wrist_left",
                                               "rollout.video_camera=wrist_left",
                                               "policies.act.image_keys=[observation.images.wrist_left]",
                                               "policies.act_subset.image_keys=[observation.images.wrist_left]",
                                               "policies.act_weak.image_keys=[observation.images.wrist_left]"])
    assert given["calib"]["camera"] == "wrist_left"

