"""cup_on_plate success rule on constructed states, progress stages, init sampling."""

import numpy as np
import pytest

from r2s_eval.twin.operator import make_operator
from tests.helpers.worlds import bundled_robot, bundled_tasks

TASKS = bundled_tasks()

TABLE_TOP_Z_M = bundled_robot().workspace_z_m

POSES = {"cup": (0.03, 0.12, 0.0), "plate": (-0.04, -0.06, 0.0)}


def _quat_about_x(angle_rad):
    return np.array([np.cos(angle_rad / 2), np.sin(angle_rad / 2), 0.0, 0.0])


def _place_cup_on_plate(env, dx_m=0.0, dz_m=0.0, tilt_rad=0.0):
    plate = env.object_poses()["plate"]["pos_world_m"]
    plate_top_z = plate[2] + env.object_dims("plate")["thickness_m"]
    env.set_object_pose("cup", [plate[0] + dx_m, plate[1], plate_top_z + dz_m], _quat_about_x(tilt_rad))


def test_registry_entry():
    task = TASKS["cup_on_plate"]
    assert task.instruction == "Pick the Cup and Place it on the Plate"
    assert task.object_names == ("cup", "plate")


def test_success_on_constructed_state(nominal_env):
    nominal_env.reset(POSES)
    _place_cup_on_plate(nominal_env, dx_m=0.02)
    assert nominal_env.is_success()
    assert nominal_env.task_progress() == 1.0
    # Still a success after the physics settles (it really rests there).
    for _ in range(3):
        nominal_env.step(nominal_env.state())
    assert nominal_env.is_success()


@pytest.mark.parametrize(
    "case, kwargs",
    [
        ("tilted", dict(tilt_rad=np.deg2rad(30))),
        ("beside_plate", dict(dx_m=0.11, dz_m=-0.008)),  # on the table next to the plate
        ("on_rim_edge", dict(dx_m=0.06)),
        ("floating", dict(dz_m=0.05)),
    ],
)
def test_near_misses_fail(nominal_env, case, kwargs):
    nominal_env.reset(POSES)
    _place_cup_on_plate(nominal_env, **kwargs)
    assert not nominal_env.is_success(), case


def test_moving_cup_is_not_success(nominal_env):
    nominal_env.reset(POSES)
    _place_cup_on_plate(nominal_env)
    adr = nominal_env._obj_dof_adr["cup"]
    nominal_env.data.qvel[adr] = 0.2  # sliding at 0.2 m/s
    assert not nominal_env.is_success()


def test_held_cup_is_not_success_then_release_is(nominal_env):
    nominal_env.reset(POSES)
    op = make_operator("cup_on_plate", nominal_env, np.random.default_rng(5))
    obs = nominal_env.observation()
    seen = {}
    for _ in range(150):
        action = op.act(obs)
        if op.done:
            break
        obs = nominal_env.step(action)
        seen.setdefault(op.phase, []).append((nominal_env.is_success(), nominal_env.task_progress(),
                                              nominal_env.grasped("cup"), nominal_env.contact_force_n()))
    # Just before release the cup is on the plate but still held: not a success.
    held_success, held_progress, held_arm, held_force = seen["lower"][-1]
    assert held_arm == op.arm and held_force > 1.0
    assert not held_success and held_progress == pytest.approx(0.8)
    # While carrying: lifted and grasped.
    assert max(p for _, p, _, _ in seen["lift"]) >= 0.6
    assert nominal_env.is_success() and nominal_env.max_task_progress == 1.0


def test_sampled_initial_poses_are_in_regions_and_apart(nominal_env, rng):
    task = TASKS["cup_on_plate"]
    for _ in range(50):
        poses = nominal_env.sample_initial_poses(rng)
        for name, (x, y, yaw) in poses.items():
            region = task.init_regions[name]
            assert region.x_range_m[0] <= x <= region.x_range_m[1]
            assert region.y_range_m[0] <= y <= region.y_range_m[1]
        gap = np.hypot(poses["cup"][0] - poses["plate"][0], poses["cup"][1] - poses["plate"][1])
        assert gap > 0.035 + 0.085 + task.clearance_m
    # And the objects really start untouched and resting on the table.
    nominal_env.reset(poses)
    assert all(abs(p["pos_world_m"][2] - TABLE_TOP_Z_M) < 2e-3 for p in nominal_env.object_poses().values())
