"""Camera poses from a ChArUco board take: the twin records one, the calibration finds its cameras
(fixed, and on an arm), and a take it cannot use is refused naming the file, camera and frames."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pandas as pd
import pytest

from r2s_eval.calib import poses
from r2s_eval.calib.board import Board, View, find_board, fit_camera
from r2s_eval.calib.cameras import calibrate_from_board, camera_errors, camera_params
from r2s_eval.calib.take import STATES_FILE, read_take
from r2s_eval.errors import DataError
from r2s_eval.sim import WorldParams
from tests.helpers.worlds import bundled_world
from r2s_eval.twin.board_take import record_board_take

TASKS = ["cup_on_plate"]
BOARD = {"squares": [9, 7], "square_m": 0.04, "marker_m": 0.03, "dictionary": "DICT_5X5_100", "thickness_m": 0.003,
         "mount": "table", "pose": {"x_m": -0.03, "y_m": 0.0, "yaw_rad": 0.0}, "min_corners": 8, "min_frames": 4,
         "max_reprojection_px": 2.0, "intrinsics": False}
TAKE = {"frames": 12, "image_size": [480, 640], "joint_spread_rad": 0.5,
        "video": {"vcodec": "h264", "preset": "ultrafast", "crf": 12}}
# A camera placed from a tape measure: centimetres and degrees off the model's pose.
TWIN = WorldParams(camera_pos_offset_m={"head_left": (0.021, -0.017, 0.026), "wrist_left": (-0.012, 0.02, 0.015)},
                   camera_rot_offset_rad={"head_left": (0.03, -0.045, 0.02), "wrist_left": (-0.04, 0.025, 0.035)},
                   encoder_noise_rad=float(np.deg2rad(0.05)), encoder_step_rad=float(2 * np.pi / 4096),
                   image_noise_std=2.0, noise_seed=5)


def world(cameras=("head_left", "wrist_left")) -> dict:
    return {**bundled_world(), "cameras": list(cameras)}


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    path = tmp_path_factory.mktemp("board") / "take"
    record_board_take(str(path), TWIN, take=TAKE, board_cfg=BOARD, world=world(), tasks=TASKS, seed=0)
    return path


def test_the_twins_take_gives_its_cameras_within_the_goals(take):
    record = calibrate_from_board(str(take), world(), BOARD, TASKS)
    errors = camera_errors(WorldParams(**camera_params(record)), TWIN, world(), TASKS, ["head_left", "wrist_left"])
    nominal = camera_errors(WorldParams(), TWIN, world(), TASKS, ["head_left", "wrist_left"])
    assert nominal["head_left"]["position_mm"] > 30 and nominal["head_left"]["rotation_deg"] > 2
    assert errors["head_left"]["position_mm"] <= 2.0 and errors["head_left"]["rotation_deg"] <= 0.2, errors
    # On the arm, 12 poses at 640 x 480 with the encoders' noise: within a few mm and tenths of a degree.
    assert errors["wrist_left"]["position_mm"] <= 4.0 and errors["wrist_left"]["rotation_deg"] <= 0.5, errors
    wrist = record["cameras"]["wrist_left"]
    assert wrist["board_from_stated"]["mm"] < 3.0  # the board found where the lab said it lies
    assert all("corners found" in why or "reprojection" in why for why in wrist["frames_left_out"].values())


def test_a_take_reads_back_with_one_state_per_frame(take):
    read = read_take(take, ["head_left", "wrist_left"], [f.name for f in _robot().features])
    assert read.states.shape == (TAKE["frames"], 14)
    assert [len(v) for v in read.images.values()] == [TAKE["frames"]] * 2
    assert read.images["head_left"][0].shape == (480, 640, 3)


def _robot():
    from r2s_eval.sim.robot import world_robot

    return world_robot(world())


def test_opencvs_charuco_corners_are_moved_to_the_pixel_centre_convention():
    """A board warped with a known homography (pixel centres at whole coordinates): the corners
    found sit on the homography's corners to a tenth of a pixel."""
    board = Board((9, 7), 0.03, 0.022, "DICT_5X5_100", 0.003)
    ppm = 2000.0
    image = board.image(ppm)
    H = np.array([[1350.0, 150.0, 120.3], [-75.0, 1500.0, 90.7], [0.3, 0.15, 1.0]])
    from_texture = np.array([[1 / ppm, 0, 0.5 / ppm], [0, 1 / ppm, 0.5 / ppm], [0, 0, 1]])
    warped = cv2.warpPerspective(image, H @ from_texture, (640, 480), flags=cv2.INTER_AREA, borderValue=255)
    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    view = find_board(np.repeat(warped[:, :, None], 3, axis=2), board, K, 0, 8)
    points = board.corners_m(view.ids)[:, :2]
    expected = (H @ np.c_[points, np.ones(len(points))].T).T
    expected = expected[:, :2] / expected[:, 2:]
    assert np.abs(np.mean(view.corners_px - expected, axis=0)).max() < 0.1


def test_a_carried_board_gives_a_fixed_camera_and_where_the_gripper_holds_it():
    """Eye to hand: the board on a moving link, the camera fixed; both poses found from the views
    alone (synthetic corners with half a pixel of noise)."""
    board = Board((9, 7), 0.03, 0.022, "DICT_5X5_100", 0.003)
    K = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
    rng = np.random.default_rng(1)
    cam_in_world = poses.pose(cv2.Rodrigues(np.array([2.5, 0.1, -0.2]))[0], (0.4, 0.1, 1.3))
    board_on_link = poses.from_vector([0.1, -0.2, 0.05, 0.02, 0.01, 0.08])
    ids = np.arange(board.n_corners)
    points = board.corners_m(ids)
    views, links = [], {}
    for frame in range(15):
        # The board in front of the camera, turned and moved a little from frame to frame.
        T_cam_from_board = poses.from_vector([*rng.uniform(-0.4, 0.4, 3), *rng.uniform(-0.15, 0.0, 2),
                                              rng.uniform(0.5, 0.8)])
        links[frame] = cam_in_world @ T_cam_from_board @ poses.inverse(board_on_link)
        cam = points @ T_cam_from_board[:3, :3].T + T_cam_from_board[:3, 3]
        uv = (cam @ K.T)[:, :2] / (cam @ K.T)[:, 2:3] + rng.normal(0, 0.5, (len(ids), 2))
        ok, rvec, tvec = cv2.solvePnP(points, uv, K, None)
        views.append(View(frame, ids, uv, poses.pose(cv2.Rodrigues(rvec)[0], tvec), 0.5))
    fixed = {f: np.eye(4) for f in links}
    fit = fit_camera(views, K, board, fixed, links, None, "free", min_frames=4, max_rms_px=2.0, where="test")
    mm, deg = poses.distance(fit.T_parent_from_cam, cam_in_world)
    assert mm < 1.0 and deg < 0.1
    assert poses.distance(fit.T_mount_from_board, board_on_link)[0] < 1.0


@pytest.fixture()
def folder_take(take, tmp_path):
    """The twin's take written as a folder of images with states.csv (the other layout)."""
    read = read_take(take, ["head_left"], [f.name for f in _robot().features])
    folder = tmp_path / "folder_take"
    (folder / "head_left").mkdir(parents=True)
    for i, image in enumerate(read.images["head_left"]):
        cv2.imwrite(str(folder / "head_left" / f"{i:06d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    table = pd.DataFrame(read.states, columns=[f.name for f in _robot().features])
    table.insert(0, "frame_index", range(len(table)))
    table.to_csv(folder / STATES_FILE, index=False)
    return folder


def test_a_folder_take_calibrates_like_the_dataset(folder_take, take):
    one = world(["head_left"])
    from_folder = calibrate_from_board(str(folder_take), one, BOARD, TASKS)["cameras"]["head_left"]
    from_dataset = calibrate_from_board(str(take), one, BOARD, TASKS)["cameras"]["head_left"]
    assert np.allclose(from_folder["pos_offset_m"], from_dataset["pos_offset_m"], atol=5e-4)


def test_a_take_whose_states_do_not_match_its_frames_is_refused(folder_take):
    (folder_take / "head_left" / "000003.png").unlink()
    with pytest.raises(DataError, match=r"states.csv has 12 joint states, .*head_left holds 11 frames"):
        calibrate_from_board(str(folder_take), world(["head_left"]), BOARD, TASKS)


def test_a_take_without_the_board_in_view_names_the_camera_and_frames(folder_take):
    blank = folder_take / "head_left"
    for png in blank.glob("*.png"):
        cv2.imwrite(str(png), np.full((480, 640, 3), 180, np.uint8))
    with pytest.raises(DataError, match=r"camera head_left: 0 usable frames, at least 4 needed; left out: frames 0-11: 0 board corners found \(0 markers\)"):
        calibrate_from_board(str(folder_take), world(["head_left"]), BOARD, TASKS)


@pytest.mark.parametrize("wrong", [{"dictionary": "DICT_4X4_50"}, {"squares": [5, 4]}])
def test_a_board_of_another_dictionary_or_size_is_refused(take, wrong):
    with pytest.raises(DataError, match=r"board take .*camera head_left.*usable frames"):
        calibrate_from_board(str(take), world(["head_left"]), {**BOARD, **wrong}, TASKS)


def test_a_missing_take_is_named(tmp_path):
    with pytest.raises(DataError, match="no such folder"):
        calibrate_from_board(str(tmp_path / "nowhere"), world(), BOARD, TASKS)
    shutil.rmtree(tmp_path, ignore_errors=True)
