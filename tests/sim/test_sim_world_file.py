"""A world's objects and tasks (the `world` config group): read and checked; a wrong entry stops
with one line naming the key and the file that set it."""

from __future__ import annotations

import copy
import re
import shutil
from pathlib import Path

import pytest

from r2s_eval.config import compose_config
from r2s_eval.errors import ConfigError
from r2s_eval.sim.assembly import load_world
from r2s_eval.sim.tasks import WORLDS_DIR, WorldError, load_tasks
from tests.helpers.worlds import BUNDLED, bundled_tasks, bundled_world

TASKS = bundled_tasks()

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_the_bundled_world_holds_the_seven_tasks():
    assert sorted(TASKS) == ["ball_in_box", "ball_in_cup", "block_from_box", "cover_ball", "cup_on_plate",
                             "stack_blocks", "upright_cup"]
    task = TASKS["block_from_box"]
    assert task.object_names == ("box", "block_a") and task.init_regions["block_a"].relative_to == "box"
    assert TASKS["upright_cup"].placement("cup") == "on_side" and TASKS["upright_cup"].arm == "behind_axis"
    assert compose_config(CONF, "demo")["world"]["tasks"] == bundled_world()["tasks"]


NEW_TASK = ("+world.tasks.ball_on_plate={instruction:'Put the Ball on the Plate',"
            "start:{ball:{x_range_m:[-0.05,-0.02],y_range_m:[-0.12,-0.09]},plate:{x_range_m:[-0.02,0.01],"
            "y_range_m:[-0.01,0.02]}},plan:[{pick:ball},{place_on:plate}],"
            "success:{all:[{on_top_of:{object:ball,support:plate}},{released:{object:ball}}]},"
            "progress:{objects:[ball],goal:{over:{object:ball,target:plate}}}}")


def test_a_new_task_is_config_alone():
    cfg = compose_config(CONF, "smoke", [NEW_TASK, "tasks=[ball_on_plate]"])
    assert cfg["tasks"] == ["ball_on_plate"] and len(cfg["world"]["tasks"]) == 8
    task = load_tasks(cfg["world"])["ball_on_plate"]
    assert task.object_names == ("ball", "plate") and task.manipulated == "ball"


def test_the_operator_does_a_task_defined_by_config_alone():
    # Where the README's added task starts (its whole smoke chain is run by hand, docs/tests.md):
    # the operator's plan for it succeeds in perturbed twins.
    from r2s_eval.twin.operator import success_rate

    cfg = compose_config(CONF, "smoke", [NEW_TASK, "tasks=[ball_on_plate]"])
    assert success_rate("ball_on_plate", episodes=2, twin=True, world=cfg["world"]) == 1.0


def _broken(old: str, new: str) -> dict:
    text = (WORLDS_DIR / f"{BUNDLED}.yaml").read_text()
    assert old in text, old
    import yaml

    return yaml.safe_load(text.replace(old, new, 1))


@pytest.mark.parametrize(("old", "new", "message"), [
    ("- on_top_of: {object: cup, support: plate}", "- on_top: {object: cup, support: plate}",
     r"world\.tasks\.cup_on_plate\.success\.all\[1\]: unknown predicate 'on_top'; predicates are \["),
    ("- on_top_of: {object: cup, support: plate}", "- on_top_of: {object: cup, support: ball}",
     r"world\.tasks\.cup_on_plate\.success: names \['ball'\], which are not objects of the task \['cup', 'plate'\]"),
    ("- on_top_of: {object: cup, support: plate}", "- on_top_of: {object: cup, surface: plate}",
     r"world\.tasks\.cup_on_plate\.success\.all\[1\]\.on_top_of: unknown parameter\(s\) \['surface'\]; missing \['support'\]"),
    ("- on_top_of: {object: cup, support: plate}", "- inside: {object: cup, container: plate}",
     r"world\.tasks\.cup_on_plate\.success\.all\[1\]\.inside: container 'plate' is a plate; inside is defined for "
     r"\['cup', 'box', 'mesh'\]"),
    ("mass_kg: 0.25", "mass_kg: -0.25", r"world\.objects\.plate\.mass_kg: must be in \(0, inf\], got -0\.25"),
    ("mass_kg: 0.25", "mass_kg: .nan", r"world\.objects\.plate\.mass_kg: must be a finite number, got nan"),
    ("kind: plate", "kind: saucer", r"world\.objects\.plate\.kind: must be one of \["),
    ("start: {cup: {x_range_m: [-0.12, 0.06], y_range_m: [-0.16, 0.16]}, plate:",
     "start: {cup: {x_range_m: [-0.12, 0.06], y_range_m: [-0.16, 0.16]}, saucer:",
     r"world\.tasks\.cup_on_plate\.start: must name objects of the world \["),
    ("y_range_m: [-0.12, 0.12]}", "y_range_m: [0.12, -0.12]}",
     r"world\.tasks\.block_from_box\.start\.box\.y_range_m: must be \[low, high\] with low <= high"),
    ("relative_to: box", "relative_to: plate", r"world\.tasks\.block_from_box\.start\.block_a\.relative_to: must name another object"),
    ("placement: on_side", "placement: sideways", r"world\.tasks\.upright_cup\.start\.cup\.placement: must be one of \["),
    ("arm: behind_axis", "arm: third", r"world\.tasks\.upright_cup\.arm: must be an arm of the robot \['left', 'right'\]"),
    ("start: {ball: {x_range_m: [-0.12, 0.06], y_range_m: [-0.16, 0.16]}, box: {x_range_m: [-0.12, 0.06], y_range_m: [-0.16, 0.16]}}",
     "start: {ball: {x_range_m: [0.0, 0.01], y_range_m: [0.0, 0.01]}, box: {x_range_m: [0.0, 0.01], y_range_m: [0.0, 0.01]}}",
     r"world\.tasks\.ball_in_box\.start: leaves no room: no draw of 1000 keeps"),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{pick: ball}, {place_in: plate}]",
     r"world\.tasks\.ball_in_box\.plan\[1\]\.place_in: must name an object of the task"),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{pick: ball}, {drop: box}]",
     r"world\.tasks\.ball_in_box\.plan\[1\]: unknown primitive .drop."),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{place_in: box}]",
     r"world\.tasks\.ball_in_box\.plan: must be a pick and one of"),
    ("      objects: [cup]\n      goal: {all: [{over", "      objects: [ball]\n      goal: {all: [{over",
     r"world\.tasks\.cup_on_plate\.progress\.objects: must list objects of the task"),
    ("    mass_kg: 0.045  # a golf ball's weight", "    mass_kg: 0.045\n    find: {hue: {hue_lo: 200, hue_hi: 10}}",
     r"world\.objects\.ball\.find\.hue\.hue_lo: must be in \[0, 179\], got 200"),
    ("    mass_kg: 0.045  # a golf ball's weight", "    mass_kg: 0.045\n    find: {prompt: ''}",
     r"world\.objects\.ball\.find\.prompt: must be a non-empty text"),
    # The robot and its rig.
    ("      model: assets/arm.xml\n      mount: {frame: left_mount}", "      model: assets/arms.xml\n      mount: {frame: left_mount}",
     r"world\.robot\.arms\.left\.model: no such model file: .*assets/arms\.xml"),
    ("  scene: assets/tabletop.xml", "  scene: {package: r2s_eval, resource: scene.xml}",
     r"world\.robot\.scene: no such model file: .*r2s_eval/scene\.xml"),
    ("  scene: assets/tabletop.xml", "  scene: {package: no_such_robots, resource: scene.xml}",
     r"world\.robot\.scene\.package: package 'no_such_robots' is not installed"),
    ("mount: {frame: right_mount}", "mount: {frame: rear_mount}",
     r"world\.robot\.arms\.right\.mount\.frame: the scene 'r2s_tabletop' has no frame 'rear_mount'"),
    ("      joints: [j1, j2, j3, j4, j5, j6]\n      home: [0.0", "      joints: [j1, j2, j3, j4, j5, j7]\n      home: [0.0",
     r"world\.robot\.arms\.left\.joints: arm\.xml has no joint 'j7'"),
    ("      joints: [j1, j2, j3, j4, j5, j6]\n      home: [0.0", "      joints: [j1, j2, j3, j4, j5, j6]\n      home: [0.0, 0.1",
     r"world\.robot\.arms\.left\.home: must be a list of 6 numbers"),
    ("        actuator: gripper", "        actuator: grip",
     r"world\.robot\.arms\.left\.gripper\.actuator: arm\.xml has no actuator 'grip'"),
    ("      ee: {site: tcp, approach: +x, jaw: +y}\n    right:", "      ee: {site: tool, approach: +x, jaw: +y}\n    right:",
     r"world\.robot\.arms\.left\.ee\.site: arm\.xml has no site 'tool'"),
    ("      ee: {site: tcp, approach: +x, jaw: +y}\n    right:", "      ee: {site: tcp, approach: +x, jaw: -x}\n    right:",
     r"world\.robot\.arms\.left\.ee: approach and jaw must be different axes"),
    ("  control_hz: 10", "  control_hz: 10\n  features: [{name: left_j1, arm: left, joint: j1}]",
     r"world\.robot\.features: no feature maps to \['left j2', .*'right gripper'\]"),
    ("  control_hz: 10", "  control_hz: 10\n  features: [{name: left_j1, arm: left, joint: j9}]",
     r"world\.robot\.features\[0\]\.joint: must be a joint of arm left"),
    ("  control_hz: 10", "  control_hz: 7",
     r"world\.robot\.control_hz: 7 Hz is not a whole number of 0\.002 s physics steps"),
    # The keys a small arm needs: the physics timestep, the grasp centre's offset, jaw collision shapes.
    ("  control_hz: 10", "  control_hz: 10\n  timestep_s: 0", r"world\.robot\.timestep_s: must be in \(0, inf\], got 0"),
    ("  control_hz: 10", "  control_hz: 10\n  timestep_s: 0.003",
     r"world\.robot\.timestep_s: 10 Hz is not a whole number of 0\.003 s physics steps"),
    ("      ee: {site: tcp, approach: +x, jaw: +y}\n    right:", "      ee: {site: tcp, pos: [0.01, 0]}\n    right:",
     r"world\.robot\.arms\.left\.ee\.pos: must be a list of 3 values"),
    ("      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]", "      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]\n      collision: {remove: [pad_a]}",
     r"world\.robot\.arms\.left\.collision\.remove: is not a key of world\.robot\.arms\.left\.collision"),
    ("      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]", "      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]\n      collision: {disable: {geoms: [pad_c]}}",
     r"world\.robot\.arms\.left\.collision\.disable\.geoms: arm\.xml has no geom 'pad_c'"),
    ("      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]", "      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]\n      collision: {disable: {bodies: [finger_c]}}",
     r"world\.robot\.arms\.left\.collision\.disable\.bodies: arm\.xml has no body 'finger_c'"),
    ("      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]",
     "      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]\n      collision: {add: [{body: finger_a, type: mesh, size: [0.01]}]}",
     r"world\.robot\.arms\.left\.collision\.add\[0\]\.type: must be one of \['box', 'sphere', 'capsule', 'cylinder', 'ellipsoid'\]"),
    ("      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]",
     "      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]\n      collision: {add: [{body: finger_a, type: box, size: [0.01, 0.01]}]}",
     r"world\.robot\.arms\.left\.collision\.add\[0\]\.size: must be a list of 3 numbers"),
    ("      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]",
     "      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]\n      collision: {add: [{body: finger_c, type: sphere, size: [0.01]}]}",
     r"world\.robot\.arms\.left\.collision\.add\[0\]\.body: arm\.xml has no body 'finger_c'"),
    ("      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]",
     "      home: [0.0, -0.2, 0.8, 0.0, 0.97, 0.0]\n      collision: {add: [{body: finger_a, type: sphere, size: [0.01], friction: [1.0]}]}",
     r"world\.robot\.arms\.left\.collision\.add\[0\]\.friction: must be a list of 3 values"),
    ("cameras: [head_left, head_right, wrist_left, wrist_right]", "cameras: [head_left, top]",
     r"world\.cameras: records \['top'\], which the rig .* does not place"),
    ("  wrist_left: {camera: wrist, arm: left}", "  wrist_left: {camera: wrist_cam, arm: left}",
     r"world\.rig\.wrist_left\.camera: the model has no camera 'left_wrist_cam'"),
    ("  head_left: {camera: head_left, look_at: [-0.03, 0.0, 0.75]}",
     "  head_left: {camera: head_left, intrinsics: {fx: 100, fy: 100, cx: 70, cy: 63.5, width: 64, height: 128}}",
     r"world\.rig\.head_left\.intrinsics\.cx: must lie inside the 64x128 image \(0\.\.63\), got 70"),
])
def test_a_wrong_entry_names_its_key(old, new, message):
    with pytest.raises(WorldError) as err:
        load_world(_broken(old, new))
    assert "\n" not in str(err.value) and re.fullmatch(message + ".*", str(err.value)), str(err.value)


def test_a_wrong_world_stops_the_config_naming_the_file(tmp_path):
    conf = Path(shutil.copytree(CONF, tmp_path / "conf"))
    world = conf / "world" / "tabletop.yaml"
    world.write_text(world.read_text().replace("- on_top_of: {object: cup, support: plate}",
                                               "- on_top: {object: cup, support: plate}"))
    with pytest.raises(ConfigError) as err:
        compose_config(conf, "smoke")
    assert str(err.value).startswith("world.tasks.cup_on_plate.success.all[1] (set in conf/world/tabletop.yaml): "
                                     "unknown predicate 'on_top'")


def test_tasks_and_suite_name_tasks_of_the_world():
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "smoke", ["tasks=[cup_on_plate,fold_towel]"])
    assert "tasks[1] (set by the command-line override 'tasks=[cup_on_plate,fold_towel]') must be a task of " \
           "world.tasks" in str(err.value)


def test_the_loaded_world_is_not_changed_by_its_reader():
    world = copy.deepcopy(bundled_world())
    load_tasks(world)
    assert world == bundled_world()


def test_how_an_object_is_found_is_the_worlds():
    """An object's explicit colour range and open-vocabulary prompt come from its world entry."""
    from r2s_eval.calib.segment import HueRange, finders, make_segmenter

    world = _broken("    mass_kg: 0.045  # a golf ball's weight",
                    "    mass_kg: 0.045\n    find: {hue: {hue_lo: 40, hue_hi: 80, sat_min: 60}, prompt: a golf ball}")
    task = load_tasks(world)["ball_in_box"]
    segmenter = make_segmenter({"type": "hsv"}, {o.name: o.rgba for o in task.objects}, finders(task.objects))
    assert segmenter.ranges["ball"] == HueRange(hue_lo=40, hue_hi=80, sat_min=60)
    assert segmenter.ranges["box"] == make_segmenter({"type": "hsv"}, {"box": task.object("box").rgba}).ranges["box"]
    assert task.object("ball").prompt == "a golf ball" and task.object("box").prompt is None
