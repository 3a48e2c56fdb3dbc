"""The seven tasks: success rules on constructed states (successes and near misses), start
poses inside their regions without collisions, and staged progress."""

from __future__ import annotations

import numpy as np
import pytest

from r2s_eval.sim.objects import KINDS, placement_quat
from r2s_eval.sim.predicates import apart
from tests.helpers.worlds import bundled_env, bundled_tasks

TASKS = bundled_tasks()

TABLE_Z = 0.75
UP = placement_quat("upright", 0.0)
DOWN = placement_quat("upside_down", 0.0)


def _tilted(angle_rad: float) -> np.ndarray:
    return np.array([np.cos(angle_rad / 2), np.sin(angle_rad / 2), 0.0, 0.0])


@pytest.fixture(scope="module")
def envs():
    made = {key: bundled_env(key, cameras=()) for key in TASKS}
    yield made
    for env in made.values():
        env.close()


def _dims(env, name):
    return env.object_dims(name)


# Each builder puts the task's objects in a constructed state: (env, variant) -> None.
# "success" must pass; every other variant is a near miss that must fail.
def _cover_ball(env, variant):
    cup_h = _dims(env, "cup")["height_m"]
    inner = _dims(env, "cup")["radius_m"] - _dims(env, "cup")["wall_m"] - _dims(env, "ball")["radius_m"]
    ball_xy = np.array([0.0, -0.05])
    cup_xy = ball_xy + {"success": [0.0, 0.0], "ball_half_out": [inner + 0.012, 0.0]}.get(variant, [0.0, 0.0])
    env.set_object_pose("ball", [*ball_xy, TABLE_Z], UP)
    cup_z = TABLE_Z + cup_h + (0.03 if variant == "cup_floating" else 0.0)
    env.set_object_pose("cup", [*cup_xy, cup_z], UP if variant == "cup_upright" else DOWN)
    if variant == "cup_upright":  # upright cup standing beside the ball
        env.set_object_pose("cup", [ball_xy[0] + 0.09, ball_xy[1], TABLE_Z], UP)


def _ball_in_box(env, variant):
    d = _dims(env, "box")
    env.set_object_pose("box", [-0.02, 0.05, TABLE_Z], placement_quat("upright", 0.4))
    ball = {"success": [-0.02, 0.05, TABLE_Z + d["floor_m"]],
            "beside_box": [-0.02, -0.08, TABLE_Z],
            "above_box": [-0.02, 0.05, TABLE_Z + d["height_m"] + 0.03]}[variant]
    env.set_object_pose("ball", ball, UP)


def _ball_in_cup(env, variant):
    d = _dims(env, "cup")
    cup_quat = _tilted(np.deg2rad(35)) if variant == "cup_tipped" else UP
    env.set_object_pose("cup", [0.0, 0.05, TABLE_Z], cup_quat)
    ball = {"success": [0.0, 0.05, TABLE_Z + d["bottom_m"]],
            "cup_tipped": [0.0, 0.05, TABLE_Z + d["bottom_m"] + 0.01],
            "beside_cup": [0.0, -0.05, TABLE_Z],
            "above_rim": [0.0, 0.05, TABLE_Z + d["height_m"] + 0.01]}[variant]
    env.set_object_pose("ball", ball, UP)


def _stack_blocks(env, variant):
    s = _dims(env, "block_b")["size_m"]
    env.set_object_pose("block_b", [0.0, 0.0, TABLE_Z], placement_quat("upright", 0.3))
    top = {"success": ([0.005, 0.0, TABLE_Z + s], placement_quat("upright", 0.6)),
           "off_centre": ([0.0, 0.019, TABLE_Z + s], UP),
           "side_by_side": ([0.0, 0.08, TABLE_Z], UP),
           "tilted": ([0.0, 0.0, TABLE_Z + s + 0.005], _tilted(np.deg2rad(30))),
           "floating": ([0.0, 0.0, TABLE_Z + s + 0.02], UP)}[variant]
    env.set_object_pose("block_a", *top)


def _stack_blocks_reversed(env, variant):
    s = _dims(env, "block_a")["size_m"]
    env.set_object_pose("block_a", [0.0, 0.0, TABLE_Z], UP)
    env.set_object_pose("block_b", [0.0, 0.0, TABLE_Z + s], UP)


def _block_from_box(env, variant):
    d = _dims(env, "box")
    s = _dims(env, "block_a")["size_m"]
    env.set_object_pose("box", [-0.02, 0.0, TABLE_Z], UP)  # outer half width along y: d["width_m"] / 2
    edge_y = d["width_m"] / 2
    block = {"success": [-0.02, edge_y + s / 2 + 0.005, TABLE_Z],
             "in_box": [-0.02, 0.0, TABLE_Z + d["floor_m"]],
             "overlapping_wall": [-0.02, edge_y + s / 2 - 0.006, TABLE_Z],
             "lifted_outside": [-0.02, edge_y + s / 2 + 0.02, TABLE_Z + 0.05]}[variant]
    env.set_object_pose("block_a", block, UP)


def _upright_cup(env, variant):
    pose = {"success": ([0.0, 0.0, TABLE_Z], UP),
            "on_side": ([0.0, 0.0, TABLE_Z + _dims(env, "cup")["base_radius_m"]], KINDS["cup"].orientation("on_side", 0.0, _dims(env, "cup"))),
            "upside_down": ([0.0, 0.0, TABLE_Z + _dims(env, "cup")["height_m"]], DOWN),
            "tilted": ([0.0, 0.0, TABLE_Z + 0.01], _tilted(np.deg2rad(30))),
            "floating": ([0.0, 0.0, TABLE_Z + 0.03], UP)}[variant]
    env.set_object_pose("cup", *pose)


CASES = {
    "cover_ball": (_cover_ball, ["ball_half_out", "cup_floating", "cup_upright"]),
    "ball_in_box": (_ball_in_box, ["beside_box", "above_box"]),
    "ball_in_cup": (_ball_in_cup, ["cup_tipped", "beside_cup", "above_rim"]),
    "stack_blocks": (_stack_blocks, ["off_centre", "side_by_side", "tilted", "floating"]),
    "block_from_box": (_block_from_box, ["in_box", "overlapping_wall", "lifted_outside"]),
    "upright_cup": (_upright_cup, ["on_side", "upside_down", "tilted", "floating"]),
}
NEAR_MISSES = [(task, variant) for task, (_, variants) in CASES.items() for variant in variants]


def _construct(env, build, variant):
    env.reset(seed=0)
    # Park every object far from the scene first so builders only place what they use.
    for i, name in enumerate(env.task.object_names):
        env.set_object_pose(name, [0.3, -0.3 + 0.2 * i, TABLE_Z], UP)
    build(env, variant)


@pytest.mark.parametrize("task", sorted(CASES))
def test_success_on_constructed_state_and_after_settling(envs, task):
    env = envs[task]
    build, _ = CASES[task]
    _construct(env, build, "success")
    assert env.is_success(), task
    assert env.task_progress() == 1.0
    for _ in range(3):  # it really rests there: still a success after physics runs
        env.step(env.state())
    assert env.is_success(), task


def test_either_block_may_be_on_top(envs):
    env = envs["stack_blocks"]
    _construct(env, _stack_blocks_reversed, "success")
    assert env.is_success()


@pytest.mark.parametrize("task, variant", NEAR_MISSES)
def test_near_misses_fail(envs, task, variant):
    env = envs[task]
    build, _ = CASES[task]
    _construct(env, build, variant)
    assert not env.is_success(), f"{task}: {variant}"


@pytest.mark.parametrize("task", sorted(CASES))
def test_moving_object_is_not_success(envs, task):
    env = envs[task]
    build, _ = CASES[task]
    _construct(env, build, "success")
    moving = env.task.manipulated
    env.data.qvel[env._obj_dof_adr[moving]] = 0.2  # sliding at 0.2 m/s
    assert not env.is_success(), task


def test_apart_is_a_footprint_test(envs):
    env = envs["block_from_box"]
    _construct(env, _block_from_box, "success")
    assert apart(env, "block_a", "box")
    # Rotating the box by 45 degrees swings its corner over the block.
    env.set_object_pose("box", [-0.02, 0.0, TABLE_Z], placement_quat("upright", np.pi / 4))
    assert not apart(env, "block_a", "box")


@pytest.mark.parametrize("task", sorted(TASKS))
def test_start_poses_in_regions_without_collisions(envs, task):
    env = envs[task]
    spec = env.task
    rng = np.random.default_rng(1)
    for _ in range(5):
        poses = env.sample_initial_poses(rng)
        for name, (x, y, yaw) in poses.items():
            region = spec.init_regions[name]
            if region.relative_to is None:
                assert region.x_range_m[0] <= x <= region.x_range_m[1]
                assert region.y_range_m[0] <= y <= region.y_range_m[1]
            assert region.yaw_range_rad[0] <= yaw <= region.yaw_range_rad[1]
        env.reset(poses)
        # Nothing moved while settling (no object started inside another or the robot) ...
        for name, pose in env.object_poses().items():
            x, y, yaw = pose["planar"]
            assert np.hypot(x - poses[name][0], y - poses[name][1]) < 2e-3, (task, name)
        # ... nothing touches the robot, no task is solved and progress starts at zero.
        assert not any(env.robot_touches(n) for n in spec.object_names)
        assert not env.is_success() and env.task_progress() == 0.0


@pytest.mark.parametrize("task", sorted(TASKS))
def test_placements_start_as_documented(envs, task):
    env = envs[task]
    env.reset(seed=3)
    for name in env.task.object_names:
        z_axis_up = 1 - 2 * (env.object_state(name)["quat_wxyz"][1] ** 2 + env.object_state(name)["quat_wxyz"][2] ** 2)
        expected = {"upright": 1.0, "upside_down": -1.0, "on_side": 0.1}[env.task.placement(name)]  # lying: ~taper
        if env.task.object(name).kind != "ball":  # a ball has no up
            assert z_axis_up == pytest.approx(expected, abs=0.05), (task, name)


def test_instructions_are_the_methods_task_names():
    assert {t.instruction for t in TASKS.values()} == {
        "Cover the Ball with the Cup",
        "Pick the Ball and Place it in the Box",
        "Pick the Ball and Place it in the Cup",
        "Pick the Cup and Place it on the Plate",
        "Stack the Two Blocks",
        "Take the Block out of the Box",
        "Upright the Fallen Cup",
    }
