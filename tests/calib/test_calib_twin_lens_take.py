"""The twin's board take when the calibration fits the lenses (``calib.cameras.board.intrinsics``):
it shows every camera what the lens fit needs (views, grid cells, tilts), as a lab's take for it
would, and the calibration fits the poses from the frames whose board lies where stated.

Each take is recorded through the twin's true lens (the C920's rational model) with its cameras
off their model poses, at 640 x 480 px."""

from __future__ import annotations

import pytest

from r2s_eval.calib.board import (LENS_MIN_CELLS, LENS_MIN_TILTS, LENS_MIN_VIEWS, MOVED_BOARD, Board, find_board,
                                  grid_cells, new_tilt)
from r2s_eval.calib.cameras import calibrate_from_board, camera_errors, camera_params, lens_errors, nominal_env
from r2s_eval.calib.take import read_take
from r2s_eval.sim import WorldParams
from r2s_eval.sim.robot import world_robot
from r2s_eval.twin.board_take import record_board_take
from r2s_eval.twin.camera import C920_RATIONAL
from r2s_eval.twin.reality import RealityEffects
from tests.helpers.worlds import bundled_world

TASKS = ["cup_on_plate"]
CAMERAS = ["head_left", "wrist_left"]
BOARD = {"squares": [9, 7], "square_m": 0.04, "marker_m": 0.03, "dictionary": "DICT_5X5_100", "thickness_m": 0.003,
         "mount": "table", "pose": {"x_m": -0.03, "y_m": 0.0, "yaw_rad": 0.0}, "min_corners": 8, "min_frames": 4,
         "max_reprojection_px": 2.0, "intrinsics": True}
TAKE = {"frames": 10, "image_size": [480, 640], "joint_spread_rad": 0.5, "lens_frames": 12,
        "video": {"vcodec": "h264", "preset": "ultrafast", "crf": 12}}
TWIN = WorldParams(camera_pos_offset_m={"head_left": (0.004, -0.003, 0.002), "wrist_left": (-0.003, 0.002, 0.003)},
                   camera_rot_offset_rad={"head_left": (0.01, -0.008, 0.012), "wrist_left": (-0.01, 0.006, 0.009)})
REALITY = RealityEffects(lens_distortion={cam: C920_RATIONAL for cam in CAMERAS})


def world(cameras=CAMERAS) -> dict:
    return {**bundled_world(), "cameras": list(cameras)}


@pytest.fixture(scope="module")
def lens_take(tmp_path_factory):
    path = tmp_path_factory.mktemp("lens_take") / "take"
    recorded = record_board_take(str(path), TWIN, take=TAKE, board_cfg=BOARD, world=world(), tasks=TASKS, seed=0,
                                 reality=REALITY)
    return path, recorded


def spread(views, size) -> tuple[int, int, int]:
    """(views, grid cells their corners cover, distinct tilts), as the lens fit counts them."""
    normals = []
    for view in views:
        if new_tilt(view, normals):
            normals.append(view.T_cam_from_board[:3, 2])
    return len(views), len(set().union(*(grid_cells(v.corners_px, size) for v in views))), len(normals)


def test_the_lens_take_shows_every_camera_what_its_lens_fit_needs(lens_take):
    path, recorded = lens_take
    lens_frames = TAKE["lens_frames"]
    assert recorded["frames"] == TAKE["frames"] + lens_frames  # the head camera's frames held up to it
    take = read_take(str(path), CAMERAS, world_robot(world()).feature_names)
    env = nominal_env(world(), TASKS)
    board = Board.from_config(BOARD)
    size = tuple(TAKE["image_size"])
    try:
        found = {cam: [v for frame, image in enumerate(take.images[cam])
                       if not isinstance(v := find_board(image, board, env.camera_K(cam, size), frame, 8), str)]
                 for cam in CAMERAS}
    finally:
        env.close()
    lying, held = ([v for v in found["head_left"] if (v.frame < TAKE["frames"]) == first] for first in (True, False))
    # The head camera over the lying board: one tilt, the middle of the image only (an arm over
    # the board may hide it in a frame or two: measured 10 of 10 frames, 4 cells).
    views, cells, tilts = spread(lying, size)
    assert views >= TAKE["frames"] - 2 and cells <= 6 and tilts == 1, (views, cells, tilts)
    # Held up to it, the board reaches every cell and leans many ways (measured 12 views, 16 cells,
    # 9 tilts).
    views, cells, tilts = spread(held, size)
    assert views == lens_frames and cells == 16 and tilts >= LENS_MIN_TILTS + 3, (views, cells, tilts)
    # The wrist camera, swept over the lying board (measured 10 views, 15 cells, 10 tilts).
    views, cells, tilts = spread([v for v in found["wrist_left"] if v.frame < TAKE["frames"]], size)
    assert views >= LENS_MIN_VIEWS and cells >= LENS_MIN_CELLS and tilts >= LENS_MIN_TILTS, (views, cells, tilts)


def test_the_lens_take_calibrates_lenses_and_poses(lens_take):
    """The calibration fits each lens from every view and each pose from the frames whose board lies
    where stated, the held-up frames named as lens views only."""
    path, _ = lens_take
    record = calibrate_from_board(str(path), world(), BOARD, TASKS)
    head = record["cameras"]["head_left"]
    held = range(TAKE["frames"], TAKE["frames"] + TAKE["lens_frames"])
    assert len(head["frames_used"]) >= TAKE["frames"] - 2 and max(head["frames_used"]) < TAKE["frames"]
    assert {f: why for f, why in head["frames_left_out"].items() if int(f) in held} == {
        str(f): MOVED_BOARD for f in held}
    assert head["intrinsics"]["cells_covered"] == 16
    assert head["intrinsics"]["views"] == len(head["frames_used"]) + TAKE["lens_frames"]
    assert record["cameras"]["wrist_left"]["intrinsics"]["cells_covered"] >= LENS_MIN_CELLS
    errors = camera_errors(WorldParams(**camera_params(record)), TWIN, world(), TASKS, CAMERAS)
    lenses = lens_errors(record, REALITY.lens_distortion, world(), TASKS)
    # The cameras within the board's goals, 2 mm and 0.2 deg (measured head 1.38 mm, 0.074 deg;
    # wrist 0.28 mm, 0.020 deg); the lenses within half a pixel over the image (measured head
    # 0.11 px RMS, wrist 0.09 px) where none leaves 2.2 and 10.3 px.
    for cam in CAMERAS:
        assert errors[cam]["position_mm"] < 2.0 and errors[cam]["rotation_deg"] < 0.2, errors
        assert lenses[cam]["distortion_px"] < 0.5 and lenses[cam]["model_px"] > 2.0, lenses


def test_a_carried_board_is_held_in_one_grip_up_to_the_fixed_camera(tmp_path):
    """``mount: left``: the twin carries the board in the left gripper, the same grip in every frame,
    so the calibration finds the fixed camera and the board on the gripper together, through the
    fitted lens."""
    path = tmp_path / "take"
    board_cfg = {**BOARD, "mount": "left"}
    recorded = record_board_take(str(path), TWIN, take=TAKE, board_cfg=board_cfg, world=world(["head_left"]),
                                 tasks=TASKS, seed=0, reality=REALITY)
    assert recorded["frames"] == TAKE["lens_frames"]
    record = calibrate_from_board(str(path), world(["head_left"]), board_cfg, TASKS)
    head = record["cameras"]["head_left"]
    assert head["intrinsics"]["cells_covered"] == 16 and len(head["frames_used"]) == TAKE["lens_frames"]
    # Measured 0.21 mm, 0.040 deg; the lens 0.24 px RMS where none leaves 2.2 px.
    errors = camera_errors(WorldParams(**camera_params(record)), TWIN, world(["head_left"]), TASKS, ["head_left"])
    assert errors["head_left"]["position_mm"] < 2.0 and errors["head_left"]["rotation_deg"] < 0.2, errors
    lens = lens_errors(record, REALITY.lens_distortion, world(["head_left"]), TASKS)["head_left"]
    assert lens["distortion_px"] < 0.5 and lens["model_px"] > 2.0, lens
