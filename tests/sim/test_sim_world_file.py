"""A world file's objects and tasks: read and checked; a wrong entry stops with one line naming
the file and the key."""

from __future__ import annotations

import re
import shutil

import pytest

from r2s_eval.errors import ConfigError
from r2s_eval.sim.tasks import BUNDLED_WORLD, TASKS, load_tasks


@pytest.fixture
def world(tmp_path):
    return shutil.copy(BUNDLED_WORLD, tmp_path / "world.yaml")


def _edit(path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def test_the_bundled_world_holds_the_seven_tasks():
    assert sorted(TASKS) == ["ball_in_box", "ball_in_cup", "block_from_box", "cover_ball", "cup_on_plate",
                             "stack_blocks", "upright_cup"]
    task = TASKS["block_from_box"]
    assert task.object_names == ("box", "block_a") and task.init_regions["block_a"].relative_to == "box"
    assert TASKS["upright_cup"].placement("cup") == "on_side" and TASKS["upright_cup"].arm == "behind_axis"


def test_a_new_task_is_an_entry_of_the_world_file(world):
    _edit(world, "tasks:\n", """tasks:
  ball_on_plate:
    instruction: Put the Ball on the Plate
    start: {ball: *full, plate: *full}
    plan: [{pick: ball}, {place_on: plate}]
    success: {all: [{over: {object: ball, target: plate}}, {released: {object: ball}}]}
    progress: {objects: [ball], goal: {over: {object: ball, target: plate}}}
""")
    tasks = load_tasks(world)
    assert len(tasks) == 8 and tasks["ball_on_plate"].object_names == ("ball", "plate")
    assert tasks["ball_on_plate"].manipulated == "ball"


@pytest.mark.parametrize(("old", "new", "message"), [
    ("- on_top_of: {object: cup, support: plate}", "- on_top: {object: cup, support: plate}",
     r"tasks\.cup_on_plate\.success\.all\[1\]: unknown predicate 'on_top'; predicates are \["),
    ("- on_top_of: {object: cup, support: plate}", "- on_top_of: {object: cup, support: ball}",
     r"tasks\.cup_on_plate\.success: names \['ball'\], which are not objects of the task \['cup', 'plate'\]"),
    ("- on_top_of: {object: cup, support: plate}", "- on_top_of: {object: cup, surface: plate}",
     r"tasks\.cup_on_plate\.success\.all\[1\]\.on_top_of: unknown parameter\(s\) \['surface'\]; missing \['support'\]"),
    ("mass_kg: 0.25", "mass_kg: -0.25", r"objects\.plate\.mass_kg: must be positive, got -0\.25"),
    ("mass_kg: 0.25", "mass_kg: .nan", r"objects\.plate\.mass_kg: must be a finite number, got nan"),
    ("kind: plate", "kind: saucer", r"objects\.plate\.kind: must be one of \["),
    ("start: {cup: *full, plate: *full}", "start: {cup: *full, saucer: *full}",
     r"tasks\.cup_on_plate\.start: must name objects of the world \["),
    ("y_range_m: [-0.12, 0.12]}", "y_range_m: [0.12, -0.12]}",
     r"tasks\.block_from_box\.start\.box\.y_range_m: must be \[low, high\] with low <= high"),
    ("relative_to: box", "relative_to: plate", r"tasks\.block_from_box\.start\.block_a\.relative_to: must name another object"),
    ("placement: on_side", "placement: sideways", r"tasks\.upright_cup\.start\.cup\.placement: must be one of \["),
    ("arm: behind_axis", "arm: third", r"tasks\.upright_cup\.arm: must be one of \["),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{pick: ball}, {place_in: plate}]",
     r"tasks\.ball_in_box\.plan\[1\]\.place_in: must name an object of the task"),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{pick: ball}, {drop: box}]",
     r"tasks\.ball_in_box\.plan\[1\]: unknown primitive .drop."),
    ("    plan: [{pick: ball}, {place_in: box}]", "    plan: [{place_in: box}]",
     r"tasks\.ball_in_box\.plan: must be a pick and one of"),
    ("      objects: [cup]\n      goal: {all: [{over", "      objects: [ball]\n      goal: {all: [{over",
     r"tasks\.cup_on_plate\.progress\.objects: must list objects of the task"),
])
def test_a_wrong_entry_names_the_file_and_the_key(world, old, new, message):
    _edit(world, old, new)
    with pytest.raises(ConfigError) as err:
        load_tasks(world)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"{world}: ") and re.search(message, text), text


def test_a_missing_world_file_names_it(tmp_path):
    with pytest.raises(ConfigError, match=r"nowhere\.yaml: no such world file"):
        load_tasks(tmp_path / "nowhere.yaml")
