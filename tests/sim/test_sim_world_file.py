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
from r2s_eval.sim.tasks import BUNDLED_WORLD, TASKS, WorldError, bundled_world, load_tasks

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


def _broken(old: str, new: str) -> dict:
    text = BUNDLED_WORLD.read_text()
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
     r"\['cup', 'box'\]"),
    ("mass_kg: 0.25", "mass_kg: -0.25", r"world\.objects\.plate\.mass_kg: must be positive, got -0\.25"),
    ("mass_kg: 0.25", "mass_kg: .nan", r"world\.objects\.plate\.mass_kg: must be a finite number, got nan"),
    ("kind: plate", "kind: saucer", r"world\.objects\.plate\.kind: must be one of \["),
    ("start: {cup: {x_range_m: [-0.12, 0.06], y_range_m: [-0.16, 0.16]}, plate:",
     "start: {cup: {x_range_m: [-0.12, 0.06], y_range_m: [-0.16, 0.16]}, saucer:",
     r"world\.tasks\.cup_on_plate\.start: must name objects of the world \["),
    ("y_range_m: [-0.12, 0.12]}", "y_range_m: [0.12, -0.12]}",
     r"world\.tasks\.block_from_box\.start\.box\.y_range_m: must be \[low, high\] with low <= high"),
    ("relative_to: box", "relative_to: plate", r"world\.tasks\.block_from_box\.start\.block_a\.relative_to: must name another object"),
    ("placement: on_side", "placement: sideways", r"world\.tasks\.upright_cup\.start\.cup\.placement: must be one of \["),
    ("arm: behind_axis", "arm: third", r"world\.tasks\.upright_cup\.arm: must be one of \["),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{pick: ball}, {place_in: plate}]",
     r"world\.tasks\.ball_in_box\.plan\[1\]\.place_in: must name an object of the task"),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{pick: ball}, {drop: box}]",
     r"world\.tasks\.ball_in_box\.plan\[1\]: unknown primitive .drop."),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{place_in: box}]",
     r"world\.tasks\.ball_in_box\.plan: must be a pick and one of"),
    ("      objects: [cup]\n      goal: {all: [{over", "      objects: [ball]\n      goal: {all: [{over",
     r"world\.tasks\.cup_on_plate\.progress\.objects: must list objects of the task"),
])
def test_a_wrong_entry_names_its_key(old, new, message):
    with pytest.raises(WorldError) as err:
        load_tasks(_broken(old, new))
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
