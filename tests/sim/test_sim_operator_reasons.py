"""The scripted operator says why an episode failed: planted failures, one short episode each."""

import copy
import re

import numpy as np
import pytest
import yaml

from r2s_eval.report.calibration_report import failure_lines, teleop_summary
from r2s_eval.sim import TabletopEnv
from r2s_eval.sim.plans import PLAN_PRIMITIVES, read_plan
from r2s_eval.sim.predicates import false_parts
from r2s_eval.sim.reading import WorldError
from r2s_eval.sim.robot import world_robot
from r2s_eval.sim.tasks import WORLDS_DIR, get_task
from r2s_eval.twin.failures import summary
from r2s_eval.twin.operator import make_operator, run_episode
from r2s_eval.twin.primitives import PRIMITIVES


@pytest.fixture(scope="module")
def bundled():
    return yaml.safe_load((WORLDS_DIR / "tabletop.yaml").read_text())


def _episode(world, max_steps, seed=0, task="stack_blocks", env_change=None):
    env = TabletopEnv(get_task(task, world), cameras=(), robot=world_robot(world))
    if env_change is not None:
        env_change(env.model)
    obs = env.reset(seed=seed)
    operator = make_operator(task, env, np.random.default_rng(seed))
    run_episode(env, operator, max_steps, obs=obs)
    return operator.failure()


def _cm(detail: str, what: str) -> float:
    return float(re.search(rf"([-+]?\d+\.\d) cm {what}", detail).group(1))


def test_an_object_out_of_reach_stops_the_approach_far_from_it(bundled):
    world = copy.deepcopy(bundled)
    world["tasks"]["stack_blocks"]["start"]["block_a"] = {"x_range_m": [0.40, 0.42], "y_range_m": [0.0, 0.02]}
    world["tasks"]["stack_blocks"]["arm"] = "left"
    failure = _episode(world, max_steps=50)
    assert (failure.phase, failure.reason) == ("approach", "target_not_reached"), failure
    assert _cm(failure.detail, "from its target") > 10  # the hand stays at the edge of its reach


def test_a_gripper_too_narrow_for_the_object_stops_on_top_of_it(bundled):
    world = copy.deepcopy(bundled)
    narrow = dict(bundled["robot"]["arms"]["left"]["gripper"], ctrl={"open": 0.015, "closed": 0.0},
                  position={"open": 0.015, "closed": 0.0}, jaw_open_m=0.015)  # jaws 3 cm apart, the block 4.5 cm
    world["robot"]["arms"]["left"]["gripper"] = world["robot"]["arms"]["right"]["gripper"] = narrow
    failure = _episode(world, max_steps=50)
    assert (failure.phase, failure.reason) == ("approach", "target_not_reached"), failure
    assert _cm(failure.detail, "above it") > 2  # the fingertips rest on the block's top


def test_a_slippery_object_slips_from_the_hand_while_lifted(bundled):
    def slippery_block(model):
        # Contacts take the larger friction of the two geoms unless one has priority: the block's
        # own friction then holds against the jaws too.
        geoms = np.flatnonzero(model.geom_bodyid == model.body("block_a").id)
        model.geom_priority[geoms] = 1
        model.geom_friction[geoms, 0] = 0.01

    failure = _episode(bundled, max_steps=75, env_change=slippery_block)
    assert (failure.phase, failure.reason) == ("lift", "slipped"), failure
    assert _cm(failure.detail, "above the table") > 3


def test_a_finger_held_past_its_range_is_named_with_its_arm(bundled):
    def narrow_finger_range(model):  # below the open command: the servo holds the finger past the limit
        for joint in ("left_finger_a", "left_finger_b"):
            model.jnt_range[model.joint(joint).id] = [0.0, 0.03]

    failure = _episode(bundled, max_steps=3, env_change=narrow_finger_range)
    assert (failure.phase, failure.reason) == ("start", "joint_out_of_range"), failure
    assert re.fullmatch(r"joint finger_a of arm left reached 0\.03\d+, range 0 to 0\.03", failure.detail)


def test_the_false_parts_of_a_task_check_are_named(bundled):
    env = TabletopEnv(get_task("cup_on_plate", bundled), cameras=(), robot=world_robot(bundled))
    env.reset(seed=0)  # the cup stands beside the plate
    parts = false_parts(env.task.success_condition, env, "tasks.cup_on_plate.success")
    assert parts == ["tasks.cup_on_plate.success.all[1].on_top_of {object: cup, support: plate}"]
    assert false_parts({"not": {"upright": {"object": "cup"}}}, env, "c") == ["c.not {'upright': {'object': 'cup'}}"]
    assert false_parts({"upright": {"object": "cup"}}, env) == []


def test_failures_are_summed_per_task_in_the_teleop_report():
    attempts = [
        {"task": "a", "attempt": 1, "success": True, "length": 90, "wall_s": 1.0},
        {"task": "a", "attempt": 2, "success": False, "length": 90, "wall_s": 1.0, "phase": "lift",
         "reason": "slipped", "detail": "..."},
        {"task": "a", "attempt": 3, "success": False, "length": 90, "wall_s": 1.0, "phase": "lift",
         "reason": "slipped", "detail": "..."},
        {"task": "b", "attempt": 1, "success": True, "length": 90, "wall_s": 1.0},
    ]
    teleop = teleop_summary(attempts)
    assert teleop["a"]["failures"] == {"lift: slipped": 2} and teleop["b"]["failures"] == {}
    assert summary(attempts) == "2 lift: slipped"
    lines = failure_lines({"tasks": {task: {"teleop": t} for task, t in teleop.items()}})
    assert lines[-1] == "  a: 2 lift: slipped"


def test_the_plan_check_and_the_operator_share_one_list_of_primitives(bundled):
    assert set(PRIMITIVES) == set(PLAN_PRIMITIVES)
    kinds = {"block_a": "block", "box": "box", "cup": "cup"}
    with pytest.raises(WorldError, match=r"plan\[1\]\.put_down_beside: the picked 'cup' is a cup; "
                                         r"put_down_beside puts down \['block'\]"):
        read_plan([{"pick": "cup"}, {"put_down_beside": "box"}], kinds, "plan")
    with pytest.raises(WorldError, match=r"plan\[1\]\.place_on: must name another object than the one picked"):
        read_plan([{"pick": "cup"}, {"place_on": "cup"}], kinds, "plan")
    with pytest.raises(WorldError, match=r"plan\[0\]\.turn_upright: 'block_a' is a block; turn_upright is defined"):
        read_plan([{"turn_upright": "block_a"}], kinds, "plan")
