"""A world's robot and camera rig as data: the dataset layout's units, a camera with a lab's
intrinsics, cameras placed by the world."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest

from r2s_eval.sim import TabletopEnv, world_robot
from r2s_eval.sim.cameras import project_points
from r2s_eval.sim.predicates import centre_m
from tests.helpers.worlds import bundled_env, bundled_robot, bundled_tasks, bundled_world

BALL_IN_BOX = bundled_tasks()["ball_in_box"]

POSES = {"ball": (-0.02, -0.06, 0.0), "box": (-0.03, 0.1, 0.0)}


def _world(**changes) -> dict:
    world = copy.deepcopy(bundled_world())
    for path, value in changes.items():
        node = world
        *parents, last = path.split(".")
        for key in parents:
            node = node[key]
        node[last] = value
    return world


def _ball_centroid_error_px(env: TabletopEnv, camera: str, size: tuple[int, int]) -> float:
    labels, names = env.render(camera, size=size, segmentation=True)
    rows, cols = np.nonzero(labels == names_index(names, "ball"))
    assert len(rows) > 20, f"the ball is not in view of {camera}"
    uv, _ = project_points(centre_m(env, "ball"), env.camera_K(camera, size), env.camera_T_world_from_cam(camera))
    return float(np.hypot(cols.mean() - uv[0, 0], rows.mean() - uv[0, 1]))


def names_index(names: dict[int, str], name: str) -> int:
    return next(label for label, n in names.items() if n == name)


@pytest.mark.parametrize("size", [(128, 128), (96, 160)])
def test_a_camera_with_intrinsics_projects_where_it_renders(size):
    """fx != fy and an off-centre principal point: the rendered ball sits where the OpenCV pinhole
    model of the rig entry puts it, at the intrinsics' resolution and at another one."""
    intrinsics = {"fx": 150.0, "fy": 135.0, "cx": 71.0, "cy": 57.5, "width": 128, "height": 128}
    world = _world(**{"rig.front": {"body": "world", "pos": [0.5, -0.05, 1.25], "look_at": [-0.03, 0.0, 0.75],
                                    "intrinsics": intrinsics}, "cameras": ["head_left", "front"]})
    env = TabletopEnv(BALL_IN_BOX, cameras=("front",), robot=world_robot(world))
    env.reset(POSES, settle=False, observe=False)
    K = env.camera_K("front", (128, 128))
    np.testing.assert_allclose(K[[0, 1, 0, 1], [0, 1, 2, 2]], [150.0, 135.0, 71.0, 57.5])
    assert _ball_centroid_error_px(env, "front", size) < 0.3
    assert _ball_centroid_error_px(env, "head_left", size) < 0.3  # a fovy camera, for comparison
    env.close()


def test_features_convert_the_datasets_units_both_ways():
    """A lab recording the left arm in degrees and its gripper 0..100: the env takes and reports its
    own layout, and the physics is the bundled world's."""
    features = [{"name": f"left_{j}.deg", "arm": "left", "joint": j, "scale": float(np.pi / 180)}
                for j in ("j1", "j2", "j3", "j4", "j5", "j6")]
    features += [{"name": "left_grip", "arm": "left", "gripper": True, "scale": 0.01}]
    features += [{"name": f"right_{j}", "arm": "right", "joint": j} for j in ("j1", "j2", "j3", "j4", "j5", "j6")]
    features += [{"name": "right_gripper", "arm": "right", "gripper": True}]
    robot = world_robot(_world(**{"robot.features": features}))
    assert robot.feature_names[:2] == ["left_j1.deg", "left_j2.deg"] and robot.action_dim == 14
    bundled = bundled_robot()
    native = bundled.from_model(bundled.home_targets())
    mine = robot.from_model(robot.home_targets())
    np.testing.assert_allclose(mine[:6], np.rad2deg(native[:6]))
    mine[6] = 60.0  # the left gripper 60 % closed
    np.testing.assert_allclose(robot.from_model(robot.to_model(mine)), mine)

    envs = [TabletopEnv(BALL_IN_BOX, cameras=(), robot=r) for r in (bundled, robot)]
    command = {id(bundled): native.copy(), id(robot): mine}
    command[id(bundled)][6] = 0.6
    for env in envs:
        env.reset(POSES)
        for _ in range(5):
            env.step(command[id(env.robot)], images=False)
    ours, theirs = envs[1].state(), envs[0].state()
    np.testing.assert_allclose(ours[:6], np.rad2deg(theirs[:6]), rtol=1e-5, atol=1e-4)
    assert ours[6] == pytest.approx(100 * theirs[6], abs=1e-3) and ours[6] > 30
    np.testing.assert_array_equal(ours[7:], theirs[7:])
    for env in envs:
        env.close()


def test_the_bundled_rig_places_the_four_cameras_as_before():
    robot = bundled_robot()
    assert robot.camera_names == ("head_left", "head_right", "wrist_left", "wrist_right")
    env = TabletopEnv(BALL_IN_BOX, cameras=(), robot=robot)
    head = env.camera_T_world_from_cam("head_left")
    # Aimed at the workspace centre: the optical axis passes through (-0.03, 0, 0.75).
    to_target = np.array([-0.03, 0.0, 0.75]) - head[:3, 3]
    np.testing.assert_allclose(head[:3, 2], to_target / np.linalg.norm(to_target), atol=1e-9)
    env.close()


def test_a_world_sets_the_physics_timestep():
    """`robot.timestep_s` overrides the scene's 2 ms: the control period is held for whole steps of it."""
    env = TabletopEnv(BALL_IN_BOX, cameras=(), robot=world_robot(_world(**{"robot.timestep_s": 0.001})))
    assert env.model.opt.timestep == 0.001 and env.n_substeps == 100
    assert bundled_env("ball_in_box", cameras=()).n_substeps == 50


def test_the_grasp_centre_is_offset_in_the_sites_frame():
    """`ee.pos` puts the grasp centre off the named site, along the site's own axes."""
    arm = copy.deepcopy(bundled_world()["robot"]["arms"]["left"])
    arm["ee"] = {**arm["ee"], "pos": [0.01, 0.0, 0.0]}  # 1 cm further along tcp's x, the approach
    shifted, bundled = (TabletopEnv(BALL_IN_BOX, cameras=(), robot=r)
                        for r in (world_robot(_world(**{"robot.arms.left": arm})), bundled_robot()))
    moved = shifted.ee_positions()["left"] - bundled.ee_positions()["left"]
    np.testing.assert_allclose(moved, 0.01 * bundled.ee_rotations()["left"][:, 0], atol=1e-9)
    np.testing.assert_allclose(shifted.ee_positions()["right"], bundled.ee_positions()["right"])


def test_collision_swaps_the_jaws_shapes_for_primitives():
    """`collision` switches a body's collision geoms off and adds collision-only primitives that
    collide as the body's own geoms did (the bundled arm's parts never touch each other)."""
    arm = copy.deepcopy(bundled_world()["robot"]["arms"]["left"])
    arm["collision"] = {"disable": {"bodies": ["finger_a"], "geoms": ["pad_b"]},
                        "add": [{"body": "finger_a", "type": "box", "size": [0.019, 0.002, 0.011], "pos": [0.045, 0.0, 0.0],
                                 "euler_deg": [0.0, 0.0, 90.0], "friction": [1.2, 0.01, 0.001]}]}
    m = TabletopEnv(BALL_IN_BOX, cameras=(), robot=world_robot(_world(**{"robot.arms.left": arm}))).model
    for name in ("left_finger_a", "left_pad_a", "left_pad_b"):
        assert m.geom(name).contype == 0 and m.geom(name).conaffinity == 0, name
    assert m.geom("right_pad_a").contype == 2 and m.geom("left_finger_b").contype == 2
    box = m.geom("left_collision_0").id
    assert m.body(m.geom_bodyid[box]).name == "left_finger_a" and m.geom_type[box] == mujoco.mjtGeom.mjGEOM_BOX
    assert (m.geom_contype[box], m.geom_conaffinity[box], m.geom_group[box]) == (2, 1, 3)
    np.testing.assert_allclose(m.geom_friction[box], [1.2, 0.01, 0.001])
    np.testing.assert_allclose(m.geom_quat[box], [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)], atol=1e-12)
    bundled = bundled_env("ball_in_box", cameras=()).model
    assert m.body("left_finger_a").mass == bundled.body("left_finger_a").mass  # the box adds no mass
