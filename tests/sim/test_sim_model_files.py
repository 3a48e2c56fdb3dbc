"""Model files as their makers ship them (r2s_eval.sim.model_files): gym-aloha's ViperX 300 as an
include fragment with its assets file and as one body of the package's bimanual model, unnamed
actuators named by their joints and unnamed geoms by their body, a file's own simulation settings
giving way to the scene's, grippers with several fingers, and the physics a world states."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from r2s_eval.sim.assembly import build_robot_model, load_world
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.model_files import load_model_spec
from r2s_eval.sim.reading import WorldError, package_dir
from r2s_eval.sim.robot import world_robot
from r2s_eval.sim.tasks import get_task
from tests.helpers.worlds import bundled_world

REPO = Path(__file__).resolve().parents[2]
ALOHA = package_dir("gym_aloha", "test") / "assets"
WHERE = "robot.arms.left.model"


@pytest.fixture
def aloha_world() -> dict:
    return yaml.safe_load((REPO / "conf" / "world" / "aloha.yaml").read_text())


def test_an_include_fragment_without_its_assets_file_names_the_key_and_what_it_misses(aloha_world):
    del aloha_world["robot"]["arms"]["right"]["model"]["assets"]
    with pytest.raises(WorldError, match=r"^world\.robot\.arms\.right\.model\.assets: vx300s_right\.xml is an include "
                                         r"fragment that uses mesh 'vx300s_1_base' \(and 10 more\)"):
        load_world(aloha_world)


def test_a_body_the_multi_arm_file_lacks_is_named_with_the_files_top_bodies(aloha_world):
    aloha_world["robot"]["arms"]["left"]["model"]["body"] = "vx300s_lft"
    with pytest.raises(WorldError, match=r"^world\.robot\.arms\.left\.model\.body: bimanual_viperx_transfer_cube\.xml "
                                         r"has no top body 'vx300s_lft'; its top bodies: \['table', 'midair', "
                                         r"'vx300s_left', 'vx300s_right', 'box'\]$"):
        load_world(aloha_world)


def test_a_finger_without_a_joint_is_named_by_its_key(aloha_world):
    aloha_world["robot"]["arms"]["left"]["gripper"]["fingers"][0]["joint"] = "vx300s_left/thumb"
    with pytest.raises(WorldError, match=r"^world\.robot\.arms\.left\.gripper\.fingers\[0\]\.joint: "
                                         r"bimanual_viperx_transfer_cube\.xml has no joint 'vx300s_left/thumb'$"):
        load_world(aloha_world)


def test_the_arm_by_body_and_by_fragment_is_the_same_arm():
    by_body = load_model_spec(ALOHA / "bimanual_viperx_transfer_cube.xml", body="vx300s_left", where=WHERE).compile()
    by_fragment = load_model_spec(ALOHA / "vx300s_left.xml", assets=[ALOHA / "vx300s_dependencies.xml"],
                                  where=WHERE).compile()
    names = [[model.joint(i).name for i in range(model.njnt)] for model in (by_body, by_fragment)]
    assert names[0] == names[1] and names[0][0] == "vx300s_left/waist" and len(names[0]) == 8
    for field in ("jnt_range", "body_mass", "body_pos", "body_inertia", "geom_size"):
        assert np.array_equal(getattr(by_body, field), getattr(by_fragment, field)), field
    # The body keeps the actuators of its own joints (the other arm's, the cube and the scene's
    # lights and cameras are gone); the fragment has none.
    assert by_body.nu == 8 and by_fragment.nu == 0 and by_body.nlight == 0 and by_body.nkey == 0


def test_unnamed_actuators_are_named_by_their_joint_and_a_clash_is_an_error(tmp_path):
    model = load_model_spec(ALOHA / "bimanual_viperx_transfer_cube.xml", body="vx300s_right", where=WHERE).compile()
    assert [model.actuator(i).name for i in range(model.nu)][-2:] == ["vx300s_right/left_finger",
                                                                       "vx300s_right/right_finger"]
    file = tmp_path / "two.xml"
    file.write_text('<mujoco><worldbody><body><joint name="hinge"/><geom size="0.1"/></body></worldbody>'
                    '<actuator><motor name="hinge" joint="hinge"/><position joint="hinge"/></actuator></mujoco>')
    with pytest.raises(WorldError, match=r"^world\.robot\.arms\.left\.model: two\.xml: an unnamed actuator of joint "
                                         r"'hinge' would be named after it"):
        load_model_spec(file, where=WHERE)


def test_the_bundled_arm_and_scene_read_as_mujoco_reads_them():
    for path in (REPO / "assets" / "arm.xml", REPO / "assets" / "tabletop.xml"):
        ours, mujocos = load_model_spec(path, where=WHERE), mujoco.MjSpec.from_file(str(path))
        for theirs, named in zip(mujocos.geoms, ours.geoms, strict=True):  # but for the names it gives
            assert theirs.name == named.name or re.fullmatch(rf"{theirs.parent.name}_geom\d", named.name)
            theirs.name = named.name
        assert ours.to_xml() == mujocos.to_xml()


def _arm_file(tmp_path: Path, old: str, new: str) -> Path:
    text = (REPO / "assets" / "arm.xml").read_text()
    assert text.count(old) == 1, old
    path = tmp_path / "maker_arm.xml"
    path.write_text(text.replace(old, new))
    return path


def _world_with_left_arm(model: Path, **keys) -> dict:
    world = bundled_world()
    world["robot"]["arms"]["left"].update(model=str(model), **keys)
    return world


def test_a_files_own_simulation_settings_give_way_to_the_scenes_without_a_warning(tmp_path, monkeypatch, capfd):
    # A maker's file stating its own step, solver tolerance, iterations and Jacobian, and a near
    # plane, attached into the bundled scene with the world's own step.
    model = _arm_file(tmp_path, '<compiler angle="radian" autolimits="true"/>',
                      '<compiler angle="radian" autolimits="true"/>\n'
                      '<option timestep="0.0025" tolerance="1e-6" iterations="50" jacobian="sparse"/>\n'
                      '<size memory="1M"/><visual><map znear="0.1"/></visual>')
    world = _world_with_left_arm(model)
    world["robot"]["timestep_s"] = 0.001
    monkeypatch.chdir(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = TabletopEnv(get_task("cup_on_plate", world), cameras=(), robot=world_robot(world))
    try:
        scene = mujoco.MjSpec.from_file(str(REPO / "assets" / "tabletop.xml")).compile()
        opt = env.model.opt
        assert opt.timestep == 0.001  # robot.timestep_s
        assert (opt.tolerance, opt.iterations, opt.jacobian) == (scene.opt.tolerance, scene.opt.iterations,
                                                                 scene.opt.jacobian)
        assert env.model.vis.map.znear == scene.vis.map.znear
    finally:
        env.close()
    out, err = capfd.readouterr()
    assert "conflict" not in (out + err).lower() and "WARNING" not in out + err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_an_unnamed_geom_is_named_by_its_body_and_a_world_can_disable_it(tmp_path):
    # The right jaw's pad left unnamed, as a maker's package may leave its jaws' collision geoms.
    model = _arm_file(tmp_path, '<geom name="pad_b" class="pad"', '<geom class="pad"')
    world = _world_with_left_arm(model, collision={"disable": {"geoms": ["finger_b_geom1"]}})
    robot, _ = load_world(world)
    compiled = build_robot_model(robot)
    pad = compiled.geom("left_finger_b_geom1")  # the body's second geom
    assert compiled.geom_bodyid[pad.id] == compiled.body("left_finger_b").id
    assert (pad.contype[0], pad.conaffinity[0]) == (0, 0)
    assert (compiled.geom("left_finger_b").contype[0], compiled.geom("right_pad_b").contype[0]) == (2, 2)

    world["robot"]["arms"]["left"]["collision"]["disable"]["geoms"] = ["finger_b_geom7"]
    with pytest.raises(WorldError) as err:
        load_world(world)
    message = str(err.value)
    assert "\n" not in message and message.startswith(
        "world.robot.arms.left.collision.disable.geoms: maker_arm.xml has no geom 'finger_b_geom7'; its colliding "
        "geoms (an unnamed one is <body>_geom<i>): [")
    assert "'finger_b_geom1'" in message and "'pad_a'" in message


def test_a_derived_geom_name_another_geom_holds_is_an_error(tmp_path):
    model = _arm_file(tmp_path, '<geom name="pad_b" class="pad"', '<geom class="pad"')
    model.write_text(model.read_text().replace('name="pad_a"', 'name="finger_b_geom1"'))
    with pytest.raises(WorldError, match=r"^world\.robot\.arms\.left\.model: maker_arm\.xml: the unnamed geom 1 of "
                                         r"body 'finger_b' would be named 'finger_b_geom1'"):
        load_model_spec(model, where=WHERE)


def test_the_aloha_worlds_fingers_close_together_with_the_physics_it_states(aloha_world):
    # The right gripper's second finger follows the first through an equality instead of its own servo.
    gripper = aloha_world["robot"]["arms"]["right"]["gripper"]
    del gripper["fingers"]
    gripper["couple"] = [{"joint": "vx300s_right/right_finger", "ratio": -1.0}]
    robot, _ = load_world(aloha_world)
    model = build_robot_model(robot)
    dof = {model.joint(j).name: model.jnt_dofadr[j] for j in range(model.njnt)}
    assert model.dof_damping[dof["left_vx300s_left/shoulder"]] == 5.0
    assert model.dof_frictionloss[dof["left_vx300s_left/left_finger"]] == 0.0
    assert model.dof_frictionloss[dof["left_vx300s_left/waist"]] == 0.0  # the package's: 50
    assert model.neq == 1 and model.actuator("right_vx300s_right/left_finger").gainprm[0] == 200.0
    with pytest.raises(KeyError):
        model.actuator("right_vx300s_right/right_finger")  # a coupled joint has no actuator of its own

    env = TabletopEnv(get_task("block_on_plate", aloha_world), cameras=(), robot=world_robot(aloha_world))
    try:
        m, d = env.model, env.data
        fingers = [m.joint(f"{arm}_vx300s_{arm}/{side}_finger").qposadr[0]
                   for arm in ("left", "right") for side in ("left", "right")]
        assert np.allclose(d.qpos[fingers], [0.057, -0.057, 0.057, -0.057], atol=2e-3)  # open at reset
        closed = env.robot.from_model({name: (arm.home, 1.0) for name, arm in env.robot.arms.items()})
        for _ in range(25):
            env.step(closed, images=False)
        assert np.allclose(d.qpos[fingers], [0.021, -0.021, 0.021, -0.021], atol=2e-3)
        assert np.allclose(env.state()[[6, 13]], 0.0, atol=0.05)  # the dataset's gripper: 0 closed .. 1 open
    finally:
        env.close()


def test_a_table_geom_the_scene_lacks_is_named_with_the_scenes_geoms():
    world = bundled_world()
    world["robot"]["workspace"]["geom"] = "table"
    with pytest.raises(WorldError) as err:
        load_world(world)
    assert re.fullmatch(r"world\.robot\.workspace\.geom: tabletop\.xml has no geom 'table'; its geoms \(an unnamed one "
                        r"is <body>_geom<i>\): \[.*'table_top'.*\]", str(err.value)), str(err.value)
