"""World, observation/action layout, cameras and determinism."""

import numpy as np
import pytest

from tests.helpers.worlds import bundled_env, bundled_robot
from r2s_eval.sim.cameras import backproject_pixels, project_points

ROBOT = bundled_robot()
TABLE_TOP_Z_M = ROBOT.workspace_z_m

POSES = {"cup": (0.0, 0.08, 0.3), "plate": (-0.05, -0.1, 0.0)}


def test_observation_layout(nominal_env):
    obs = nominal_env.reset(POSES)
    assert obs["observation.state"].shape == (14,) == (ROBOT.action_dim,)
    assert obs["observation.state"].dtype == np.float32
    for cam in ROBOT.camera_names:
        img = obs[f"observation.images.{cam}"]
        assert img.shape == (128, 128, 3) and img.dtype == np.uint8
        assert img.std() > 5  # not a blank frame
    # Grippers start open (0), arms at home: the state equals the home action.
    assert obs["observation.state"][6] == pytest.approx(0.0, abs=1e-3)
    assert obs["observation.state"][13] == pytest.approx(0.0, abs=1e-3)


def test_reset_places_objects_resting(nominal_env):
    nominal_env.reset(POSES)
    poses = nominal_env.object_poses()
    for name, (x, y, yaw) in POSES.items():
        p = poses[name]
        np.testing.assert_allclose(p["pos_world_m"][:2], [x, y], atol=2e-3)
        assert p["pos_world_m"][2] == pytest.approx(TABLE_TOP_Z_M, abs=2e-3)
        assert p["yaw_rad"] == pytest.approx(yaw, abs=1e-2)
    assert not nominal_env.is_success()
    assert nominal_env.contact_force_n() == 0.0


def test_gripper_and_arm_track_action(nominal_env):
    obs = nominal_env.reset(POSES)
    action = obs["observation.state"].astype(float).copy()
    action[0] += 0.3  # left base yaw
    action[6] = 1.0  # close left gripper (nothing in it)
    for _ in range(10):
        obs = nominal_env.step(action)
    state = obs["observation.state"]
    assert state[0] == pytest.approx(action[0], abs=0.02)
    assert state[6] == pytest.approx(1.0, abs=0.05)
    assert state[13] == pytest.approx(0.0, abs=0.05)
    assert nominal_env.time_s == pytest.approx(1.0)


def test_projection_lands_on_object_pixels(nominal_env):
    nominal_env.reset(POSES)
    size = (128, 128)
    for cam in ("head_left", "head_right"):
        labels, names = nominal_env.render(cam, size=size, segmentation=True)
        label_of = {v: k for k, v in names.items()}
        K = nominal_env.camera_K(cam, size)
        T = nominal_env.camera_T_world_from_cam(cam)
        poses = nominal_env.object_poses()
        cup_centre = poses["cup"]["pos_world_m"] + [0, 0, nominal_env.object_dims("cup")["height_m"] / 2]
        plate_top = poses["plate"]["pos_world_m"] + [0, 0, nominal_env.object_dims("plate")["thickness_m"]]
        uv, depth = project_points(np.array([cup_centre, plate_top]), K, T)
        assert np.all(depth > 0)
        for (u, v), name in zip(np.round(uv).astype(int), ("cup", "plate")):
            assert labels[v, u] == label_of[name], (cam, name)
        # The flat plate's mask centroid matches its projected centre within ~1.5 px.
        rows, cols = np.nonzero(labels == label_of["plate"])
        assert np.hypot(cols.mean() - uv[1, 0], rows.mean() - uv[1, 1]) < 1.5
        # Back-projection inverts projection.
        np.testing.assert_allclose(backproject_pixels(uv, depth, K, T), [cup_centre, plate_top], atol=1e-9)


def test_wrist_camera_sees_its_own_finger(nominal_env):
    nominal_env.reset(POSES)
    labels, names = nominal_env.render("wrist_left", segmentation=True)
    pad = nominal_env.data.geom("left_pad_a").xpos
    uv, depth = project_points(pad, nominal_env.camera_K("wrist_left"), nominal_env.camera_T_world_from_cam("wrist_left"))
    u, v = np.round(uv[0]).astype(int)
    assert depth[0] > 0 and 0 <= u < 128 and 0 <= v < 128
    assert names[labels[v, u]] == "robot_left"


def test_all_objects_visible_in_first_head_frame(nominal_env, rng):
    for _ in range(5):
        nominal_env.reset(nominal_env.sample_initial_poses(rng))
        for cam in ("head_left", "head_right"):
            labels, names = nominal_env.render(cam, segmentation=True)
            for name in ("cup", "plate"):
                mask = labels == {v: k for k, v in names.items()}[name]
                assert mask.sum() > 20, (cam, name)
                # Fully visible: no mask pixel on the image border.
                assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def test_same_seed_same_trajectory():
    def rollout():
        env = bundled_env(cameras=("head_left",))
        obs = env.reset(seed=3)
        action = obs["observation.state"].astype(float)
        action[7:13] += np.linspace(-0.2, 0.2, 6)
        states = [env.step(action)["observation.state"] for _ in range(5)]
        return np.array(states), env.render("head_left"), env.object_poses()["cup"]["pos_world_m"]

    s1, img1, cup1 = rollout()
    s2, img2, cup2 = rollout()
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(img1, img2)
    np.testing.assert_array_equal(cup1, cup2)
