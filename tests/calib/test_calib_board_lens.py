"""A camera's lens from a ChArUco board take (``calib.cameras.board.intrinsics``): fitted from views
seen through a known lens, the poses then found through it, the distortion carried into the
calibrated sim and scored against the twin's true lens (its reality record's, OpenCV's rational
model); a take too sparse for it refused in one line; and without it, the pose fit alone.

The views are drawn here through the lens: each pixel of the distorted image traced back to its
ray (OpenCV's iterative undistortion), the ray met with the board's plane and the printed board
sampled there, at twice the resolution and then area-averaged."""

from __future__ import annotations

import dataclasses
import json
import re

import cv2
import numpy as np
import pandas as pd
import pytest

from r2s_eval.calib import poses
from r2s_eval.calib.board import (LENS_MIN_VIEWS, Board, View, board_on_table, find_board, fit_camera, fit_lens,
                                  lens_pixels)
from r2s_eval.calib.cameras import calibrate_from_board, camera_errors, camera_params, lens_errors, score_calibration
from r2s_eval.calib.take import STATES_FILE
from r2s_eval.errors import DataError
from r2s_eval.report.calibration_report import camera_lines
from r2s_eval.sim import WorldParams, load_world_params
from r2s_eval.sim.build import make_env
from r2s_eval.sim.robot import world_robot
from r2s_eval.twin.board_take import record_board_take
from r2s_eval.twin.camera import C920_RATIONAL
from r2s_eval.twin.reality import RealityEffects, load_reality_effects, reality_record
from tests.helpers.worlds import bundled_world

TASKS = ["cup_on_plate"]
BOARD = {"squares": [9, 7], "square_m": 0.04, "marker_m": 0.03, "dictionary": "DICT_5X5_100", "thickness_m": 0.003,
         "mount": "table", "pose": {"x_m": -0.03, "y_m": 0.0, "yaw_rad": 0.0}, "min_corners": 8, "min_frames": 4,
         "max_reprojection_px": 2.0, "intrinsics": True}
SIZE = (480, 640)  # (height, width)
# A Logitech C920's OpenCV calibration at 640 x 480: (k1, k2, p1, p2, k3).
C920 = (0.121, -0.262, 0.0, 0.0, 0.103)
# The lab's camera: its focal lengths and principal point off the datasheet's (the nominal K).
K_TRUE = np.array([[626.3, 0.0, 322.1], [0.0, 624.9, 236.4], [0.0, 0.0, 1.0]])
K_NOMINAL = np.array([[620.0, 0.0, 319.5], [0.0, 620.0, 239.5], [0.0, 0.0, 1.0]])
SUPERSAMPLE = 2
PX_PER_M = 3000.0  # the printed board's texels: about a drawn pixel each at half a metre


def board() -> Board:
    return Board.from_config(BOARD)


def lens_rays(K: np.ndarray, distortion, size_hw=SIZE) -> np.ndarray:
    """Each drawn (supersampled) pixel's ray, normalised coordinates (h, w, 2)."""
    h, w = size_hw[0] * SUPERSAMPLE, size_hw[1] * SUPERSAMPLE
    v, u = np.mgrid[0:h, 0:w].astype(float)
    # A drawn pixel's centre in the image's pixel-centre convention.
    pixels = np.stack([(u + 0.5) / SUPERSAMPLE - 0.5, (v + 0.5) / SUPERSAMPLE - 0.5], axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    return cv2.undistortPointsIter(pixels, K, np.asarray(distortion, float), None, None, criteria).reshape(h, w, 2)


def lens_view(rays: np.ndarray, T_cam_from_board: np.ndarray, printed: np.ndarray) -> np.ndarray:
    """The board at ``T_cam_from_board`` through the lens of ``rays``, RGB uint8, white around it."""
    R, t = T_cam_from_board[:3, :3], T_cam_from_board[:3, 3]
    directions = np.dstack([rays, np.ones(rays.shape[:2])])
    reach = (R[:, 2] @ t) / (directions @ R[:, 2])  # along each ray to the board's plane
    on_board = (reach[..., None] * directions - t) @ R  # in the board's frame (m)
    map_u = (on_board[..., 0] * PX_PER_M - 0.5).astype(np.float32)  # texel centres at (k + 0.5) / px_per_m
    map_v = (on_board[..., 1] * PX_PER_M - 0.5).astype(np.float32)
    map_u[reach <= 0] = -1e6  # behind the camera: no board
    drawn = cv2.remap(printed, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    grey = cv2.resize(drawn, (rays.shape[1] // SUPERSAMPLE, rays.shape[0] // SUPERSAMPLE), interpolation=cv2.INTER_AREA)
    return np.repeat(grey[:, :, None], 3, axis=2)


def facing(u_px: float, v_px: float, depth_m: float, tilt_rad: tuple[float, float], turn_rad: float) -> np.ndarray:
    """``T_cam_from_board`` of the board's centre on the ray of pixel (u, v) of ``K_TRUE``'s
    pinhole, ``depth_m`` away, its face towards the camera tilted about x and y, turned about z."""
    R = (cv2.Rodrigues(np.array([tilt_rad[0], 0.0, 0.0]))[0] @ cv2.Rodrigues(np.array([0.0, tilt_rad[1], 0.0]))[0]
         @ cv2.Rodrigues(np.array([0.0, 0.0, turn_rad]))[0])
    width, height = board().size_m
    centre = depth_m * np.linalg.solve(K_TRUE, [u_px, v_px, 1.0])
    return poses.pose(R, centre - R @ np.array([width / 2, height / 2, 0.0]))


def placed_views() -> list[np.ndarray]:
    """Twelve board poses: its centre over a 3 x 3 grid of the image and three times at the centre,
    tilted by 25 deg six ways."""
    rng = np.random.default_rng(0)
    tilt = np.deg2rad(25.0)
    tilts = [(tilt, 0.0), (0.0, tilt), (-tilt, 0.0), (0.0, -tilt), (0.7 * tilt, 0.7 * tilt), (-0.7 * tilt, 0.7 * tilt)]
    centres = [(u, v) for v in (0.2, 0.5, 0.8) for u in (0.2, 0.5, 0.8)] + [(0.5, 0.5)] * 3
    return [facing(u * SIZE[1], v * SIZE[0], rng.uniform(0.55, 0.7), tilts[i % 6], rng.uniform(-0.2, 0.2))
            for i, (u, v) in enumerate(centres)]


@pytest.fixture(scope="module")
def through_the_lens():
    """The twelve views through the C920's lens and the lab's K, found as a take's frames are (with
    the nominal K): (the views, each view's true T_cam_from_board)."""
    rays, printed = lens_rays(K_TRUE, C920), board().image(PX_PER_M)
    truth = placed_views()
    views = [find_board(lens_view(rays, T, printed), board(), K_NOMINAL, frame, 8) for frame, T in enumerate(truth)]
    assert not any(isinstance(v, str) for v in views), views
    return views, truth


def over_the_image(K: np.ndarray, size_hw=SIZE) -> np.ndarray:
    """Rays (normalised, (N, 2)) through a grid of pixels spanning the image of ``K``'s pinhole."""
    u, v = np.meshgrid(np.linspace(0.0, size_hw[1] - 1.0, 64), np.linspace(0.0, size_hw[0] - 1.0, 48))
    return (np.c_[u.ravel(), v.ravel(), np.ones(u.size)] @ np.linalg.inv(K).T)[:, :2]


def rms_px(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def test_a_lens_is_recovered_from_views_across_the_image(through_the_lens):
    views, _ = through_the_lens
    lens = fit_lens(views, K_NOMINAL, SIZE, board(), max_rms_px=2.0, where="camera head_left")
    assert len(lens.views) == 12 and not lens.left_out and lens.corners == sum(len(v.ids) for v in views)
    assert lens.cells_covered == 16 and lens.tilts == 6
    rays = over_the_image(K_TRUE)
    true = lens_pixels(rays, K_TRUE, C920)
    # The lens's own distortion (through the lab's K) to a tenth or two of a pixel over the image
    # (measured 0.12 px); without a lens the image is 3.1 px off.
    assert rms_px(lens_pixels(rays, K_TRUE, lens.distortion), true) < 0.25
    assert rms_px(lens_pixels(rays, K_TRUE, np.zeros(5)), true) > 2.5
    # Focal lengths to 0.3 % (measured 0.1 %), the principal point to a pixel (measured 0.6 px).
    assert np.allclose(np.diag(lens.K)[:2], np.diag(K_TRUE)[:2], rtol=3e-3)
    assert np.hypot(*(lens.K[:2, 2] - K_TRUE[:2, 2])) < 1.5
    # The corners explained to the detector's precision with the distortion, not without it.
    assert lens.rms_px < 0.15 and lens.pinhole_rms_px > 2 * lens.rms_px


def test_the_pose_through_the_fitted_lens_meets_the_board_goals(through_the_lens):
    """A fixed camera and the board carried through the twelve poses (a stated pose on its holder):
    through the fitted lens the camera is found within the board's goals (2 mm, 0.2 deg), through
    the nominal pinhole K a centimetre off."""
    views, truth = through_the_lens
    camera = poses.pose(cv2.Rodrigues(np.array([2.3, 0.1, 0.2]))[0], (0.3, -0.2, 1.1))
    holder = {frame: camera @ T for frame, T in enumerate(truth)}
    world = {frame: np.eye(4) for frame in holder}
    lens = fit_lens(views, K_NOMINAL, SIZE, board(), max_rms_px=2.0, where="camera head_left")
    fit = fit_camera(lens.views, lens.K, board(), world, holder, np.eye(4), "fixed", min_frames=4, max_rms_px=2.0,
                     where="camera head_left", distortion=lens.distortion)
    mm, deg = poses.distance(fit.T_parent_from_cam, camera)
    assert mm < 1.5 and deg < 0.1 and fit.rms_px < 0.2, (mm, deg, fit.rms_px)  # measured 0.7 mm, 0.06 deg
    pinhole = fit_camera(views, K_NOMINAL, board(), world, holder, np.eye(4), "fixed", min_frames=4, max_rms_px=2.0,
                         where="camera head_left")
    assert poses.distance(pinhole.T_parent_from_cam, camera)[0] > 5.0  # measured 12 mm


def projected_views(truth: list[np.ndarray]) -> list[View]:
    """Views of the board's corners projected through the lens (no image), those in the image."""
    b, out = board(), []
    ids = np.arange(b.n_corners)
    for frame, T in enumerate(truth):
        cam = b.corners_m(ids) @ T[:3, :3].T + T[:3, 3]
        uv = lens_pixels(cam[:, :2] / cam[:, 2:3], K_TRUE, C920)
        inside = np.all((uv >= 0) & (uv <= [SIZE[1] - 1, SIZE[0] - 1]), axis=1)
        out.append(View(frame, ids[inside], uv[inside], T, 0.0))
    return out


@pytest.mark.parametrize("sparse, missing", [
    ("few", rf"5 views of the board, at least {LENS_MIN_VIEWS} needed \(left out: frames 1, 3, 5, 7, 9-11: 0 board "
            r"corners found \(0 markers\)\)"),
    ("central", r"its corners in 4 of the image's 16 cells \(4 x 4\), at least 12 needed"),
    ("one tilt", r"the board at 1 tilt \(5 deg apart or more\), at least 3 needed"),
])
def test_a_take_too_sparse_for_a_lens_is_refused_in_one_line(sparse, missing):
    truth = placed_views()
    if sparse == "central":  # far away, its centre near the image's: every corner in the middle four cells
        truth = [facing(320 + 10 * np.sin(i), 240 + 10 * np.cos(i), 1.6, (0.3 * np.sin(i), 0.3 * np.cos(i)), 0.0)
                 for i in range(12)]
    elif sparse == "one tilt":  # a fixed camera and a board lying still, filling the image: one view, again
        truth = [facing(320.0, 240.0, 0.42, (0.1, 0.05), 0.1)] * 12
    views = projected_views(truth)
    left_out = {}
    if sparse == "few":  # the image's corners and centre, at three tilts: only the count falls short
        kept = [0, 2, 4, 6, 8]
        views = [views[f] for f in kept]
        left_out = {f: "0 board corners found (0 markers)" for f in range(12) if f not in kept}
    with pytest.raises(DataError) as refused:
        fit_lens(views, K_NOMINAL, SIZE, board(), max_rms_px=2.0, where="board take lab_take, camera head_left",
                 left_out=left_out)
    message = str(refused.value)
    assert "\n" not in message
    assert message.startswith("board take lab_take, camera head_left: too sparse a take to fit the lens")
    assert re.search(missing, message) and ";" not in message, message  # what is missing, and only that


@pytest.fixture(scope="module")
def still_board_take(tmp_path_factory):
    """The twin's take of the fixed head camera as it records one without the lens fit: the board
    lying still on the table."""
    path = tmp_path_factory.mktemp("board") / "take"
    take = {"frames": 8, "image_size": list(SIZE), "joint_spread_rad": 0.5, "lens_frames": 12,
            "video": {"vcodec": "h264", "preset": "ultrafast", "crf": 12}}
    record_board_take(str(path), WorldParams(), take=take, board_cfg={**BOARD, "intrinsics": False},
                      world=one_camera("head_left"), tasks=TASKS, seed=0)
    return path


def one_camera(camera: str) -> dict:
    return {**bundled_world(), "cameras": [camera]}


def test_a_fixed_camera_over_a_board_lying_still_gives_no_lens(still_board_take):
    with pytest.raises(DataError, match=r"^board take .*, camera head_left: too sparse a take to fit the lens "
                                        r"\(intrinsics\): its corners in 4 of the image's 16 cells .*; the board at "
                                        r"1 tilt \(5 deg apart or more\), at least 3 needed: turn the board or the "
                                        r"camera between frames$"):
        calibrate_from_board(str(still_board_take), one_camera("head_left"), BOARD, TASKS)


def test_without_intrinsics_the_record_is_the_pose_fit_alone(still_board_take):
    record = calibrate_from_board(str(still_board_take), one_camera("head_left"), {**BOARD, "intrinsics": False}, TASKS)
    assert set(record["cameras"]["head_left"]) == {"pos_offset_m", "rot_offset_rad", "frames_used", "frames_left_out",
                                                   "reprojection_px", "std_position_mm", "std_rotation_deg"}
    assert camera_params(record)["lens_distortion"] == {}
    assert lens_errors(record, {"head_left": C920_RATIONAL}, one_camera("head_left"), TASKS) == {}
    calibrated = {"cameras": record, "appearance": {}}
    assert "lens" not in score_calibration({"board": record}, calibrated, WorldParams(), one_camera("head_left"), TASKS,
                                           true_lenses={"head_left": C920_RATIONAL})


# The wrist camera placed off its model pose, as in the board tests; its true lens is the twin's
# reality record's (OpenCV's rational model), which its world parameters never carry.
WRIST_TWIN = WorldParams(camera_pos_offset_m={"wrist_left": (-0.012, 0.02, 0.015)},
                         camera_rot_offset_rad={"wrist_left": (-0.04, 0.025, 0.035)})
WRIST_REALITY = RealityEffects(lens_distortion={"wrist_left": C920_RATIONAL})


@pytest.fixture(scope="module")
def wrist_lens_take(tmp_path_factory):
    """A folder take of the left wrist camera through the twin's true lens (the C920's rational
    model through its model K, as the twin records): the arm's poses drawn around home and kept,
    14 of them, where they show the lying board over most of the image; each frame the board
    alone, drawn through the lens from the camera's true pose."""
    world = one_camera("wrist_left")
    robot = world_robot(world)
    env = make_env(TASKS[0], world, WRIST_TWIN, cameras=())
    rng = np.random.default_rng(7)
    b = board()
    pose = BOARD["pose"]
    T_world_from_board = board_on_table(b, pose["x_m"], pose["y_m"], pose["yaw_rad"], robot.workspace_z_m)
    ids = np.arange(b.n_corners)
    K = env.camera_K("wrist_left", SIZE)
    candidates = []
    try:
        for _ in range(400):
            joints = {name: arm.home.copy() for name, arm in robot.arms.items()}
            joints["left"] = joints["left"] + rng.uniform(-0.6, 0.6, len(joints["left"]))
            state = robot.from_model({a: (q, 0.0) for a, q in joints.items()})
            env.pose_robot(state)
            T = poses.inverse(env.camera_T_world_from_cam("wrist_left")) @ T_world_from_board
            cam = b.corners_m(ids) @ T[:3, :3].T + T[:3, 3]
            if np.any(cam[:, 2] < 0.1):
                continue
            uv = lens_pixels(cam[:, :2] / cam[:, 2:3], K, C920_RATIONAL)
            inside = np.all((uv >= 8) & (uv <= [SIZE[1] - 9, SIZE[0] - 9]), axis=1)
            if inside.sum() >= 20:
                cells = {(int(u * 4 // SIZE[1]), int(v * 4 // SIZE[0])) for u, v in uv[inside]}
                candidates.append((state, T, cells))
    finally:
        env.close()
    chosen, covered = [], set()
    for _ in range(14):  # most new cells first, as an operator watching the feed would aim
        best = max(range(len(candidates)), key=lambda i: len(candidates[i][2] - covered))
        chosen.append(candidates.pop(best))
        covered |= chosen[-1][2]
    assert len(covered) >= 14, covered
    folder = tmp_path_factory.mktemp("lens") / "take"
    (folder / "wrist_left").mkdir(parents=True)
    rays, printed = lens_rays(K, C920_RATIONAL), b.image(PX_PER_M)
    for frame, (_, T, _) in enumerate(chosen):
        cv2.imwrite(str(folder / "wrist_left" / f"{frame:06d}.png"), lens_view(rays, T, printed))
    table = pd.DataFrame([state for state, _, _ in chosen], columns=robot.feature_names)
    table.insert(0, "frame_index", range(len(table)))
    table.to_csv(folder / STATES_FILE, index=False)
    return folder


def test_a_wrist_cameras_lens_reaches_the_calibrated_sim_and_is_scored(wrist_lens_take, tmp_path):
    world = one_camera("wrist_left")
    record = calibrate_from_board(str(wrist_lens_take), world, BOARD, TASKS)
    fit = record["cameras"]["wrist_left"]
    lens = fit["intrinsics"]
    assert lens["image_size"] == list(SIZE) and lens["views"] == 14 and lens["tilts"] >= 3
    assert lens["corners"] > 14 * 20 and lens["cells_covered"] >= 14
    # Measured 0.18 px with the distortion, 1.65 px without it.
    assert lens["reprojection_px"]["with_distortion"] < 0.3 and lens["reprojection_px"]["without_distortion"] > 1.0
    # The twin's K is the model's; five coefficients fitted to the rational lens trade a little of
    # its denominator for focal length (measured -0.44 %).
    assert abs(lens["focal_from_model_pct"]["fy"]) < 0.75
    # The pose through the lens: within the board's goals (measured 1.06 mm, 0.095 deg).
    errors = camera_errors(WorldParams(**camera_params(record)), WRIST_TWIN, world, TASKS, ["wrist_left"])["wrist_left"]
    assert errors["position_mm"] <= 2.0 and errors["rotation_deg"] <= 0.2, errors
    # The fitted distortion is what the calibrated sim is built with.
    sim = WorldParams(**camera_params(record))
    assert sim.lens_distortion == {"wrist_left": tuple(lens["distortion"])}
    (tmp_path / "world_params.json").write_text(json.dumps({"params": dataclasses.asdict(sim)}))
    assert load_world_params(tmp_path / "world_params.json") == sim  # as calib_appearance writes it
    # Scored against the twin's true lens, read from its reality record as calib_error reads the
    # twin's file (its world parameters carry no lens): within the half pixel over the
    # image (measured 0.28 px RMS, 1.29 px at worst), where no lens leaves 10.3 px.
    twin_file = tmp_path / "twin_params.json"
    twin_file.write_text(json.dumps({"params": dataclasses.asdict(WRIST_TWIN), **reality_record(WRIST_REALITY)}))
    assert load_world_params(twin_file).lens_distortion == {}
    true_lenses = load_reality_effects(twin_file).lens_distortion
    assert true_lenses == {"wrist_left": C920_RATIONAL}
    scored = lens_errors(record, true_lenses, world, TASKS)["wrist_left"]
    assert scored["distortion_px"] <= 0.5 and scored["model_px"] > 5.0, scored
    # Against a five-coefficient truth instead (the rational lens's denominator dropped) the same
    # fit scores differently (no lens: 7.7 px): the score is the reality record's lens, all eight.
    five = lens_errors(record, {"wrist_left": C920_RATIONAL[:5]}, world, TASKS)["wrist_left"]
    assert abs(five["model_px"] - scored["model_px"]) > 0.5, (five, scored)
    report = score_calibration({"board": record}, {"cameras": record, "appearance": {}}, load_world_params(twin_file),
                               world, TASKS, true_lenses=true_lenses)
    assert report["lens"] == {"board": {"wrist_left": scored}}
    assert any(line.startswith("lens wrist_left (board, 640 x 480 px): distortion ") for line in camera_lines(report))
    # Without a reality record the twin's cameras are pinholes: the fitted lens is all error.
    pinhole = score_calibration({"board": record}, {"cameras": record, "appearance": {}}, WRIST_TWIN, world, TASKS)
    assert pinhole["lens"]["board"]["wrist_left"]["model_px"] < 1e-9
    assert pinhole["lens"]["board"]["wrist_left"]["distortion_px"] > 5.0


def test_a_lens_of_eight_coefficients_projects_as_opencv_does():
    """The scoring's lens (``lens_pixels``) with OpenCV's rational model's eight coefficients is
    ``cv2.projectPoints``'s."""
    rays = over_the_image(K_NOMINAL)
    opencv = cv2.projectPoints(np.c_[rays, np.ones(len(rays))], np.zeros(3), np.zeros(3), K_NOMINAL,
                               np.array(C920_RATIONAL))[0].reshape(-1, 2)
    assert np.abs(lens_pixels(rays, K_NOMINAL, C920_RATIONAL) - opencv).max() < 1e-9
    assert np.abs(lens_pixels(rays, K_NOMINAL, C920_RATIONAL[:5]) - opencv).max() > 1.0  # the denominator counts
