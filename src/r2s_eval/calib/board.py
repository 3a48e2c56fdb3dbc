"""Camera poses from a ChArUco board take: the board, finding it in a frame, and the fit.

A take is a short recording of a ChArUco board (OpenCV's ``cv2.aruco``) with the arm's joint
states. With the board lying on the table at a pose the lab states, a fixed camera's pose comes
from each frame's ``solvePnP`` against it, and a camera on an arm (a wrist camera) gets its pose
on its link from the arm's poses at each frame (hand-eye); its views can also find where the
board lies (``planar``: slid and turned on the table), which checks the statement. With the
board carried by an arm, the fixed cameras and the board's pose on the link are found together
(eye to hand, ``cv2.calibrateHandEye`` to start). Every estimate is then refined over all frames
at once by least squares on the corners' reprojection error.

The board's own frame is OpenCV's: origin at the top-left corner of the printed image, x along
its columns, y along its rows, z into the board (away from a camera that sees its face).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

from r2s_eval.calib import poses
from r2s_eval.errors import ConfigError, DataError


CHARUCO_HALF_PIXEL = 0.5


@dataclass(frozen=True)
class Board:
    """A ChArUco board: ``squares`` (columns, rows), square and marker side (m), the ArUco
    dictionary's OpenCV name (e.g. ``DICT_5X5_100``), its thickness (m: lying on the table, its
    face is that far above the table top)."""

    squares: tuple[int, int]
    square_m: float
    marker_m: float
    dictionary: str
    thickness_m: float

    @classmethod
    def from_config(cls, cfg: Mapping, where: str = "calib.cameras.board") -> Board:
        name = str(cfg["dictionary"])
        if not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
            raise ConfigError(f"{where}.dictionary: {name!r} is not one of OpenCV's ArUco dictionaries "
                              f"(e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250)")
        if not 0 < float(cfg["marker_m"]) < float(cfg["square_m"]):
            raise ConfigError(f"{where}: marker_m ({cfg['marker_m']}) must be positive and smaller than "
                              f"square_m ({cfg['square_m']})")
        if float(cfg["thickness_m"]) <= 0:
            raise ConfigError(f"{where}.thickness_m: must be positive, got {cfg['thickness_m']}")
        return cls(tuple(int(n) for n in cfg["squares"]), float(cfg["square_m"]), float(cfg["marker_m"]), name,
                   float(cfg["thickness_m"]))

    @functools.cached_property
    def cv(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, dictionary)

    @property
    def size_m(self) -> tuple[float, float]:
        """(width along the columns, height along the rows)."""
        return self.squares[0] * self.square_m, self.squares[1] * self.square_m

    @property
    def n_corners(self) -> int:
        return (self.squares[0] - 1) * (self.squares[1] - 1)

    def image(self, px_per_m: float) -> np.ndarray:
        """The printed board, grey uint8, ``px_per_m`` pixels per metre, no margin."""
        width, height = (int(round(s * px_per_m)) for s in self.size_m)
        return self.cv.generateImage((width, height), marginSize=0)

    def corners_m(self, ids: np.ndarray) -> np.ndarray:
        """The inner corners ``ids`` in the board's frame, (N, 3)."""
        return np.asarray(self.cv.getChessboardCorners(), float)[np.asarray(ids, int).ravel()]


def board_on_table(board: Board, x_m: float, y_m: float, yaw_rad: float, table_z_m: float) -> np.ndarray:
    """``T_world_from_board`` of a board lying face up on the table: its centre at (x, y) on the
    table top (its face ``board.thickness_m`` above it), its columns along the world direction
    ``yaw_rad`` (0: +x)."""
    x_axis = np.array([np.cos(yaw_rad), np.sin(yaw_rad), 0.0])
    z_axis = np.array([0.0, 0.0, -1.0])  # into the board: down into the table
    y_axis = np.cross(z_axis, x_axis)
    width, height = board.size_m
    centre = np.array([x_m, y_m, table_z_m + board.thickness_m])
    return poses.pose(np.column_stack([x_axis, y_axis, z_axis]), centre - width / 2 * x_axis - height / 2 * y_axis)


@dataclass(frozen=True)
class View:
    """The board in one frame: its corners found (ids, pixels) and this frame's own pose of it."""

    frame: int
    ids: np.ndarray
    corners_px: np.ndarray  # (N, 2)
    T_cam_from_board: np.ndarray
    rms_px: float


def find_board(image_rgb: np.ndarray, board: Board, K: np.ndarray, frame: int, min_corners: int) -> View | str:
    """The board's view in one frame, or why there is none (too few corners, no marker)."""
    detector = cv2.aruco.CharucoDetector(board.cv)
    corners, ids, _, marker_ids = detector.detectBoard(cv2.cvtColor(image_rgb, cv2.COLOR_RGB2GRAY))
    found = 0 if ids is None else len(ids)
    if found < max(4, min_corners):
        markers = 0 if marker_ids is None else len(marker_ids)
        return f"{found} board corners found ({markers} markers), fewer than {max(4, min_corners)}"
    points = board.corners_m(ids)
    # OpenCV's ChArUco corners sit half a pixel right of and below the pixel-centre convention
    # its own warps, MuJoCo's renders and every K here use (checked against a board warped with
    # a known homography): without this, a camera 0.8 m away comes out about 4 mm off.
    corners = corners.reshape(-1, 2).astype(float) - CHARUCO_HALF_PIXEL
    ok, rvec, tvec = cv2.solvePnP(points, corners, K, None, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return "solvePnP found no pose for the corners"
    T = poses.pose(cv2.Rodrigues(rvec)[0], tvec)
    rms = _rms(_project(points, K, T) - corners)
    return View(frame, np.asarray(ids).ravel(), corners, T, rms)


def _project(points_m: np.ndarray, K: np.ndarray, T_cam_from_points: np.ndarray) -> np.ndarray:
    cam = points_m @ T_cam_from_points[:3, :3].T + T_cam_from_points[:3, 3]
    uv = cam @ K.T
    return uv[:, :2] / uv[:, 2:3]


def _rms(residual_px: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.square(residual_px), axis=-1))))


@dataclass
class CameraFit:
    """One camera's pose from a take: ``T_parent_from_cam`` (OpenCV camera frame in its parent
    body's frame), the board's pose on what holds it, the frames used and left out (with why),
    the reprojection error and the pose's standard error from the fit."""

    T_parent_from_cam: np.ndarray
    T_mount_from_board: np.ndarray
    board_found: bool  # the board's pose was fitted (not the stated one)
    frames_used: list[int]
    frames_left_out: dict[int, str] = field(default_factory=dict)
    rms_px: float = 0.0
    std_position_mm: float = 0.0
    std_rotation_deg: float = 0.0


BOARD_FREEDOM = ("fixed", "planar", "free")


def fit_camera(views: Sequence[View], K: np.ndarray, board: Board, T_world_from_parent: Mapping[int, np.ndarray],
               T_world_from_mount: Mapping[int, np.ndarray], T_mount_from_board: np.ndarray | None,
               board_freedom: str, *, min_frames: int, max_rms_px: float, where: str,
               left_out: Mapping[int, str] | None = None) -> CameraFit:
    """A camera's pose from its views of the board (each view's frame indexes the parent's and the
    board holder's world poses). ``T_mount_from_board``: the board's stated pose on its holder;
    ``board_freedom``: ``fixed`` (the stated pose is the board's), ``planar`` (a board lying on the
    table: found from the views by sliding and turning it on the table from the stated pose) or
    ``free`` (found from scratch, hand-eye; needs the camera or the board to move with the arm).
    Views whose own reprojection error exceeds ``max_rms_px`` after the fit are left out and the
    fit repeated once; fewer than ``min_frames`` usable views is an error naming ``where`` and
    every frame left out with why (``left_out``: those the board was not found in)."""
    frames = [v.frame for v in views]
    if len(frames) >= 2 and board_freedom != "fixed":
        camera_moves = _moves([T_world_from_parent[f] for f in frames])
        if camera_moves == _moves([T_world_from_mount[f] for f in frames]):
            raise DataError(f"{where}: the board's pose must be stated when "
                            + ("camera and board move together" if camera_moves else "neither camera nor board moves"))
    if board_freedom != "free" and T_mount_from_board is None:
        raise DataError(f"{where}: a {board_freedom} board needs its stated pose")
    left_out = dict(left_out or {})
    views = list(views)
    for attempt in range(2):  # a fit, then once more without the frames it could not explain
        if len(views) < min_frames:
            raise DataError(f"{where}: {len(views)} usable frames, at least {min_frames} needed"
                            + (f"; left out: {_said(left_out)}" if left_out else ""))
        T_cam, T_board = _initial(views, T_world_from_parent, T_world_from_mount, T_mount_from_board)
        fit = _refine(views, K, board, T_world_from_parent, T_world_from_mount, T_cam, T_board, board_freedom)
        bad = {v.frame: f"reprojection error {rms:.2f} px after the fit (limit {max_rms_px:g})"
               for v, rms in zip(views, fit.per_view_rms) if rms > max_rms_px}
        if not bad or attempt == 1:
            break
        left_out.update(bad)
        views = [v for v in views if v.frame not in bad]
    return CameraFit(fit.T_parent_from_cam, fit.T_mount_from_board, board_freedom != "fixed",
                     [v.frame for v in views], left_out, fit.rms_px, fit.std_position_mm, fit.std_rotation_deg)


def _said(reasons: Mapping[int, str]) -> str:
    """Frames left out, those left out for the same reason together: ``frames 0-3, 7: why``."""
    by_reason: dict[str, list[int]] = {}
    for frame, why in sorted(reasons.items()):
        by_reason.setdefault(why, []).append(frame)
    return "; ".join(f"{'frame' if len(frames) == 1 else 'frames'} {_ranges(frames)}: {why}"
                     for why, frames in by_reason.items())


def _ranges(frames: list[int]) -> str:
    runs, start = [], frames[0]
    for prev, cur in zip(frames, frames[1:] + [None]):
        if cur != prev + 1 if cur is not None else True:
            runs.append(str(start) if start == prev else f"{start}-{prev}")
            start = cur
    return ", ".join(runs)


def _moves(world_poses: Sequence[np.ndarray]) -> bool:
    first = world_poses[0]
    return any(max(poses.distance(first, T)) > 1e-6 for T in world_poses[1:])


def _initial(views, T_world_from_parent, T_world_from_mount, T_mount_from_board):
    """A first pose of the camera (and of the board on its holder): from a stated board, each
    view's PnP gives the camera (averaged); otherwise OpenCV's hand-eye solution (Park)."""
    if T_mount_from_board is not None:
        T_cam = poses.mean_pose([
            poses.inverse(T_world_from_parent[v.frame]) @ T_world_from_mount[v.frame] @ T_mount_from_board
            @ poses.inverse(v.T_cam_from_board) for v in views])
        return T_cam, T_mount_from_board
    camera_moves = _moves([T_world_from_parent[v.frame] for v in views])
    if camera_moves:  # eye in hand: the board fixed on its holder, the camera on a moving link
        holder = [T_world_from_parent[v.frame] for v in views]
    else:  # eye to hand: the board on a moving link, the camera fixed
        holder = [poses.inverse(T_world_from_mount[v.frame]) for v in views]
    R, t = cv2.calibrateHandEye([T[:3, :3] for T in holder], [T[:3, 3] for T in holder],
                                [v.T_cam_from_board[:3, :3] for v in views], [v.T_cam_from_board[:3, 3] for v in views],
                                method=cv2.CALIB_HAND_EYE_PARK)
    X = poses.pose(R, t)
    if camera_moves:
        T_cam = X  # the camera in its (moving) parent
    else:  # X: the camera in the world
        T_cam = poses.inverse(T_world_from_parent[views[0].frame]) @ X
    T_board = poses.mean_pose([
        poses.inverse(T_world_from_mount[v.frame]) @ T_world_from_parent[v.frame] @ T_cam @ v.T_cam_from_board
        for v in views])
    return T_cam, T_board


def _planar(v) -> np.ndarray:
    """A slide (dx, dy, m) and turn (dyaw, rad) on the table, about the world's vertical."""
    c, s = np.cos(v[2]), np.sin(v[2])
    return poses.pose(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), (v[0], v[1], 0.0))


@dataclass
class _Refined:
    T_parent_from_cam: np.ndarray
    T_mount_from_board: np.ndarray
    per_view_rms: list[float]
    rms_px: float
    std_position_mm: float
    std_rotation_deg: float


def _refine(views, K, board, T_world_from_parent, T_world_from_mount, T_cam, T_board, freedom: str) -> _Refined:
    points = [board.corners_m(v.ids) for v in views]

    def board_pose(x):
        if freedom == "free":
            return poses.from_vector(x[6:])
        if freedom == "planar":
            return _planar(x[6:]) @ T_board
        return T_board

    def residuals(x):
        cam, held = poses.from_vector(x[:6]), board_pose(x)
        out = []
        for v, pts in zip(views, points):
            T_cam_from_board = (poses.inverse(T_world_from_parent[v.frame] @ cam)
                                @ T_world_from_mount[v.frame] @ held)
            out.append((_project(pts, K, T_cam_from_board) - v.corners_px).ravel())
        return np.concatenate(out)

    extra = {"free": poses.to_vector(T_board), "planar": np.zeros(3), "fixed": np.zeros(0)}[freedom]
    x0 = np.r_[poses.to_vector(T_cam), extra]
    result = least_squares(residuals, x0, method="lm", x_scale="jac")
    r = result.fun.reshape(-1, 2)
    sizes = np.cumsum([len(p) for p in points])[:-1]
    per_view = [_rms(part) for part in np.split(r, sizes)]
    # Standard errors from the Gauss-Newton curvature, sigma^2 (J^T J)^-1: what the corners'
    # scatter allows; a bias common to every frame (a static camera sees one image) is not in it.
    dof = max(1, result.fun.size - x0.size)
    sigma2 = float(result.fun @ result.fun) / dof
    cov = sigma2 * np.linalg.pinv(result.jac.T @ result.jac)
    return _Refined(poses.from_vector(result.x[:6]), board_pose(result.x), per_view, _rms(r),
                    1000.0 * float(np.sqrt(np.trace(cov[3:6, 3:6]))), float(np.rad2deg(np.sqrt(np.trace(cov[:3, :3])))))
