"""No silent fallback to the bundled world: an environment, a twin, the scripted operator and the
video judge are given their world, and without one each stops saying what to pass."""

from __future__ import annotations

import numpy as np
import pytest

from r2s_eval.errors import ConfigError
from r2s_eval.judge import make_judge
from r2s_eval.sim import TabletopEnv, get_task, world_config
from r2s_eval.twin import sample_twin_params
from r2s_eval.twin.operator import success_rate
from tests.helpers.worlds import bundled_robot


def test_an_environment_needs_the_worlds_task_and_robot(bundled_world):
    task = get_task("cup_on_plate", bundled_world)
    with pytest.raises(TypeError, match="robot"):
        TabletopEnv(task, cameras=())
    with pytest.raises(ConfigError, match=r"task 'cup_on_plate' is not a task of a world; pass get_task\(key, world\)"):
        TabletopEnv("cup_on_plate", cameras=(), robot=bundled_robot())
    with pytest.raises(TypeError, match="world"):
        get_task("cup_on_plate")


def test_a_twin_needs_the_worlds_objects_and_robot():
    with pytest.raises(TypeError, match="object_names.*robot"):
        sample_twin_params(np.random.default_rng(0))
    with pytest.raises(TypeError, match="world"):
        success_rate("cup_on_plate", episodes=1)


def test_the_video_judge_needs_the_worlds_tasks():
    judge = make_judge({"backend": "video"})  # building it checks its settings only (the config check)
    with pytest.raises(ConfigError, match=r"knows no world's tasks; call know_tasks"):
        judge.identity()


def test_a_world_is_named_or_given_as_a_file(tmp_path):
    assert world_config("tabletop")["objects"]["cup"]["kind"] == "cup"
    with pytest.raises(ConfigError, match=r"unknown world 'tabletopp': the worlds are \[.*'tabletop'"):
        world_config("tabletopp")
    (tmp_path / "lab.yaml").write_text("objects: {}\n")
    with pytest.raises(ConfigError, match="not a world file"):
        world_config(tmp_path / "lab.yaml")
