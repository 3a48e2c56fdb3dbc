"""Camera poses from a ChArUco board take: the board, finding it in a frame, and the fit.

A take is a short recording of a ChArUco board (OpenCV's ``cv2.aruco``) with the arm's joint
states. With the board lying on the table at a pose the lab states, a fixed camera's pose comes
from each frame's ``solvePnP`` against it, and a camera on an arm (a wrist camera) gets its pose
on its link from the arm's poses at each frame (hand-eye); its views can also find where the
board lies (``planar``: slid and turned on the table), which checks the statement. With the
board carried by an arm, the fixed cameras and the board's pose on the link are found together
(eye to hand, ``cv2.calibrateHandEye`` to start). Every estimate is then refined over all frames
at once by least squares on the corners' reprojection error.

A camera's lens (``fit_lens``, ``calib.cameras.board.intrinsics``) can be fitted from the same
views first: its focal lengths, principal point and OpenCV's distortion (k1, k2, p1, p2, k3 on
normalised coordinates) by ``cv2.calibrateCamera``, the pose fit then projecting through them. A
take that shows the board too few times, over too little of the image or at too few tilts to pin
the lens down is refused (the ``LENS_*`` thresholds). Such a take may lift a stated board off its
pose and hold it up to a fixed camera: those views fit the lens only (``views_of_stated_board``).

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
    # OpenCV's ChArUco corners sit half a pixel right of and below the pixel-centre convention
    # its own warps, MuJoCo's renders and every K here use (checked against a board warped with
    # a known homography): without this, a camera 0.8 m away comes out about 4 mm off.
    corners = corners.reshape(-1, 2).astype(float) - CHARUCO_HALF_PIXEL
    return solve_view(frame, ids, corners, board, K)


def solve_view(frame: int, ids: np.ndarray, corners_px: np.ndarray, board: Board, K: np.ndarray,
               distortion: np.ndarray | None = None) -> View | str:
    """The board's pose in one frame from its corners (pixel-centre convention) through ``K`` and,
    when given, the lens's ``distortion``; or why there is none."""
    points = board.corners_m(ids)
    ok, rvec, tvec = cv2.solvePnP(points, corners_px, K, distortion, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return "solvePnP found no pose for the corners"
    T = poses.pose(cv2.Rodrigues(rvec)[0], tvec)
    rms = _rms(_project(points, K, T, distortion) - corners_px)
    return View(frame, np.asarray(ids).ravel(), corners_px, T, rms)


def lens_pixels(xy_normalised: np.ndarray, K: np.ndarray, distortion) -> np.ndarray:
    """Pixels (N, 2) of rays at normalised coordinates ``xy_normalised`` (x/z, y/z; (N, 2))
    through OpenCV's lens model: ``distortion`` (k1, k2, p1, p2, k3, or the rational model's
    eight: k1, k2, p1, p2, k3, k4, k5, k6), then ``K`` (what ``cv2.projectPoints`` computes)."""
    coefficients = [float(v) for v in distortion]
    if len(coefficients) not in (5, 8):
        raise ValueError(f"a lens has 5 or 8 distortion coefficients (OpenCV's order), got {len(coefficients)}")
    k1, k2, p1, p2, k3, k4, k5, k6 = coefficients + [0.0] * (8 - len(coefficients))
    x, y = xy_normalised[:, 0], xy_normalised[:, 1]
    r2 = x * x + y * y
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.c_[xd, yd, np.ones_like(xd)] @ np.asarray(K, float)[:2].T


def _project(points_m: np.ndarray, K: np.ndarray, T_cam_from_points: np.ndarray,
             distortion: np.ndarray | None = None) -> np.ndarray:
    cam = points_m @ T_cam_from_points[:3, :3].T + T_cam_from_points[:3, 3]
    if distortion is not None:
        return lens_pixels(cam[:, :2] / cam[:, 2:3], K, distortion)
    uv = cam @ K.T
    return uv[:, :2] / uv[:, 2:3]


def _rms(residual_px: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.square(residual_px), axis=-1))))


# What a take must show of the board before its lens is fitted. The distortion grows towards the
# image's edges and corners, and OpenCV's polynomial extrapolates wildly past the corners it saw:
# the corners must reach most of a coarse grid over the image. The focal lengths and principal
# point separate from the board's distance only through views that tilt the board differently
# (Zhang's planar calibration needs three orientations). Eight views: each adds six unknowns of
# its own pose to the lens's nine, and OpenCV's guides ask for ten or more.
LENS_MIN_VIEWS = 8
LENS_GRID = (4, 4)  # (columns, rows) of the coverage grid over the image
LENS_MIN_CELLS = 12  # grid cells holding a corner of some view, of the 16
LENS_MIN_TILTS = 3
LENS_TILT_STEP_DEG = 5.0  # two views whose board normals are this far apart are two tilts


@dataclass
class Lens:
    """A camera's intrinsics fitted from its views of the board, at ``image_size`` (height,
    width): ``K`` and ``distortion`` (k1, k2, p1, p2, k3), the views used (their poses solved
    through the lens) and left out (why), the corners used, the reprojection error (RMS over the
    corners, each view at its own pose) with the distortion and with a pinhole ``K`` refitted
    without it, and how the views spread (grid cells covered, distinct tilts)."""

    K: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]
    views: list[View]
    left_out: dict[int, str]
    corners: int
    rms_px: float
    pinhole_rms_px: float
    cells_covered: int
    tilts: int


def fit_lens(views: Sequence[View], K_nominal: np.ndarray, image_size: tuple[int, int], board: Board, *,
             max_rms_px: float, where: str, left_out: Mapping[int, str] | None = None) -> Lens:
    """The lens of a camera from its views of the board (``cv2.calibrateCamera`` started from
    ``K_nominal``, the model's). A take too sparse for it (fewer than ``LENS_MIN_VIEWS`` views,
    corners in fewer than ``LENS_MIN_CELLS`` cells of the grid, fewer than ``LENS_MIN_TILTS``
    tilts) is a one-line error naming ``where`` and what is missing. Views whose own error
    exceeds ``max_rms_px`` are left out and the fit repeated once."""
    views, left_out, dropped = list(views), dict(left_out or {}), {}
    for attempt in range(2):
        cells, tilts = _lens_spread(views, image_size, where, {**left_out, **dropped})
        K, distortion, per_view, rms = _calibrate(views, board, K_nominal, image_size, where, with_distortion=True)
        bad = {v.frame: f"reprojection error {r:.2f} px in the lens fit (limit {max_rms_px:g})"
               for v, r in zip(views, per_view) if r > max_rms_px}
        if not bad or attempt == 1:
            break
        dropped.update(bad)
        views = [v for v in views if v.frame not in bad]
    pinhole_rms = _calibrate(views, board, K_nominal, image_size, where, with_distortion=False)[3]
    posed = []
    for v in views:
        solved = solve_view(v.frame, v.ids, v.corners_px, board, K, distortion)
        if isinstance(solved, str):
            dropped[v.frame] = solved
        else:
            posed.append(solved)
    return Lens(K, distortion, (int(image_size[0]), int(image_size[1])), posed, dropped,
                sum(len(v.ids) for v in posed), rms, pinhole_rms, cells, tilts)


def grid_cells(corners_px: np.ndarray, image_size, grid: tuple[int, int] = LENS_GRID) -> set[tuple[int, int]]:
    """The cells (column, row) of the ``grid`` (columns, rows) over an image of ``image_size``
    (height, width) that hold one of the corners (N, 2)."""
    height, width = image_size
    columns, rows = grid
    return {(min(columns - 1, max(0, int(u * columns // width))), min(rows - 1, max(0, int(v * rows // height))))
            for u, v in corners_px}


def new_tilt(view: View, normals: Sequence[np.ndarray]) -> bool:
    """Whether the board's normal in ``view`` is ``LENS_TILT_STEP_DEG`` or more from each of
    ``normals`` (camera frame): a tilt the lens fit has not seen."""
    normal = view.T_cam_from_board[:3, 2]
    return all(np.rad2deg(np.arccos(np.clip(normal @ seen, -1.0, 1.0))) >= LENS_TILT_STEP_DEG for seen in normals)


def _lens_spread(views: Sequence[View], image_size, where: str, left_out: Mapping[int, str]) -> tuple[int, int]:
    """(grid cells the corners cover, distinct tilts of the board); an error naming what is
    missing when the views cannot pin the lens down."""
    columns, rows = LENS_GRID
    cells = len(set().union(*(grid_cells(v.corners_px, image_size) for v in views)))
    tilts: list[np.ndarray] = []  # one board normal (camera frame) per tilt
    for v in views:
        if new_tilt(v, tilts):
            tilts.append(v.T_cam_from_board[:3, 2])
    missing = []
    if len(views) < LENS_MIN_VIEWS:
        missing.append(f"{len(views)} views of the board, at least {LENS_MIN_VIEWS} needed"
                       + (f" (left out: {_said(left_out)})" if left_out else ""))
    if cells < LENS_MIN_CELLS:
        missing.append(f"its corners in {cells} of the image's {columns * rows} cells ({columns} x {rows}), at least "
                       f"{LENS_MIN_CELLS} needed: show it near the image's edges and corners")
    if len(tilts) < LENS_MIN_TILTS:
        missing.append(f"the board at {len(tilts)} {'tilt' if len(tilts) == 1 else 'tilts'} "
                       f"({LENS_TILT_STEP_DEG:g} deg apart or more), at least {LENS_MIN_TILTS} needed: turn the "
                       f"board or the camera between frames")
    if missing:
        raise DataError(f"{where}: too sparse a take to fit the lens (intrinsics): " + "; ".join(missing))
    return cells, len(tilts)


def _calibrate(views: Sequence[View], board: Board, K_guess: np.ndarray, image_size, where: str, *,
               with_distortion: bool):
    """``cv2.calibrateCamera`` over the views (each at its own pose): (K, distortion, each view's
    RMS, the RMS over every corner); without distortion, a pinhole K alone (the distortion terms
    held at zero)."""
    objects = [board.corners_m(v.ids).astype(np.float32) for v in views]
    images = [v.corners_px.astype(np.float32) for v in views]
    flags = cv2.CALIB_USE_INTRINSIC_GUESS
    if not with_distortion:
        flags |= cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    try:
        _, K, distortion, rvecs, tvecs = cv2.calibrateCamera(
            objects, images, (int(image_size[1]), int(image_size[0])), np.array(K_guess, float), np.zeros(5),
            flags=flags, criteria=criteria)
    except cv2.error as err:  # degenerate corners OpenCV cannot start from: the take's fault, named
        raise DataError(f"{where}: OpenCV could not fit the lens to the views: {err.err}") from err
    distortion = np.asarray(distortion, float).ravel()[:5]
    residuals = [cv2.projectPoints(board.corners_m(v.ids), r, t, K, distortion)[0].reshape(-1, 2) - v.corners_px
                 for r, t, v in zip(rvecs, tvecs, views)]
    return K, distortion, [_rms(r) for r in residuals], _rms(np.concatenate(residuals))


# A take that also fits the lenses may show the board off its stated pose: a lab lifts it and
# carries it through a fixed camera's view, which a board lying still cannot give (one tilt).
# Such views serve the lens fit only. A view shows the stated board when the camera pose it
# implies is within these of the pose most views imply: a single view's pose scatters by
# millimetres and a tenth of a degree, a lifted board moves it by decimetres and tens of degrees.
STATED_BOARD_MM = 25.0
STATED_BOARD_DEG = 3.0
MOVED_BOARD = "the board away from its stated pose (a lens view only)"


def views_of_stated_board(views: Sequence[View], T_world_from_parent: Mapping[int, np.ndarray],
                          T_world_from_board: Mapping[int, np.ndarray]) -> tuple[list[View], dict[int, str]]:
    """The views that show the board where it is stated (``T_world_from_board``, per frame) and
    the frames of the others, with why. Each view implies a pose of the camera in its parent; the
    kept views are those within ``STATED_BOARD_MM`` and ``STATED_BOARD_DEG`` of the pose that most
    views agree with (ties: the earliest frame's)."""
    implied = [poses.inverse(T_world_from_parent[v.frame]) @ T_world_from_board[v.frame]
               @ poses.inverse(v.T_cam_from_board) for v in views]

    def agree(a: np.ndarray, b: np.ndarray) -> bool:
        mm, deg = poses.distance(a, b)
        return mm <= STATED_BOARD_MM and deg <= STATED_BOARD_DEG

    if not views:
        return [], {}
    centre = implied[int(np.argmax([sum(agree(a, b) for b in implied) for a in implied]))]
    kept = [view for view, T in zip(views, implied) if agree(T, centre)]
    moved = {view.frame: MOVED_BOARD for view, T in zip(views, implied) if not agree(T, centre)}
    return kept, moved


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
               left_out: Mapping[int, str] | None = None, distortion: np.ndarray | None = None) -> CameraFit:
    """A camera's pose from its views of the board (each view's frame indexes the parent's and the
    board holder's world poses). ``T_mount_from_board``: the board's stated pose on its holder;
    ``board_freedom``: ``fixed`` (the stated pose is the board's), ``planar`` (a board lying on the
    table: found from the views by sliding and turning it on the table from the stated pose) or
    ``free`` (found from scratch, hand-eye; needs the camera or the board to move with the arm).
    Views whose own reprojection error exceeds ``max_rms_px`` after the fit are left out and the
    fit repeated once; fewer than ``min_frames`` usable views is an error naming ``where`` and
    every frame left out with why (``left_out``: those the board was not found in). ``distortion``:
    the lens's (``fit_lens``; None: a pinhole ``K``), the views' poses solved through it."""
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
        fit = _refine(views, K, board, T_world_from_parent, T_world_from_mount, T_cam, T_board, board_freedom,
                      distortion)
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


def _refine(views, K, board, T_world_from_parent, T_world_from_mount, T_cam, T_board, freedom: str,
            distortion: np.ndarray | None = None) -> _Refined:
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
            out.append((_project(pts, K, T_cam_from_board, distortion) - v.corners_px).ravel())
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
