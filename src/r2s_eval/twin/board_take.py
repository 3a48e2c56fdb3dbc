"""The twin's board take: a ChArUco board lying on the table, the arms moving through poses, every
recorded camera at its native resolution, recorded as a lab records one (a LeRobotDataset v3 of
one episode: joint states as the encoders read them, the commands, one video per camera).

The board is printed from ``cv2.aruco`` onto a thin plate at the pose the calibration config
states (``calib.cameras.board.pose``): the lab's statement is exact here. The arms hold each
pose still (a frame per pose), so a frame is the kinematics of the twin's true joint angles: the
first frame at home, then each arm's joints spread uniformly around home within their limits,
drawn again until the cameras the arm carries see the whole board.

When the calibration also fits the lenses (``calib.cameras.board.intrinsics``), the take is what a
lab records for that (``lens_take_plan``): a lens needs the board at several tilts and reaching
the image's corners, which a board lying still never shows a fixed camera. The arms carrying
cameras pose them so the lying board sweeps over their images (each frame the pose, among poses
aiming the camera at it and draws around home, that shows the board in the most grid cells not
yet covered, then at a new tilt); then, for each fixed camera, an arm picks the board up by the
middle of an edge and holds it facing the camera, tilted and moved over the image
(``teleop.board_take.lens_frames`` frames, chosen from a grid of placements and tilts the arm
reaches). The calibration fits the lenses from every view and the poses from the views of the
board lying where stated (``r2s_eval.calib.board.views_of_stated_board``). A board carried
throughout (``mount: <arm>``) stays in that arm's gripper, in one grip.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field

import cv2
import mujoco
import numpy as np

from r2s_eval.calib import poses
from r2s_eval.calib.board import Board, View, board_on_table, find_board, grid_cells, new_tilt
from r2s_eval.data import DatasetRecorder, lerobot_features
from r2s_eval.errors import ConfigError
from r2s_eval.sim import TabletopEnv, WorldParams
from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.arm_ik import ArmIK
from r2s_eval.sim.assembly import build_model, ee_site
from r2s_eval.sim.build import configured_task
from r2s_eval.sim.robot import Robot, world_robot
from r2s_eval.twin.reality import RealityEffects, RealityEnv
from r2s_eval.twin.scene import scene_adder
from r2s_eval.twin.servos import weaken_gripper

log = logging.getLogger("r2s_eval.board_take")

TAKE_TASK = "ChArUco board take"
_TRIES = 200  # draws per arm and frame before a pose that does not show the board is kept
_TEXTURE_PX_PER_M = 5000  # 0.2 mm per texel: finer than any camera here resolves


def board_adder(board: Board, x_m: float, y_m: float, yaw_rad: float, table_z_m: float, movable: bool = False):
    """A function adding the printed board on a thin plate lying on the table (no contacts);
    ``movable``: a mocap body an arm can pick up (``place_board``)."""

    def add(spec: mujoco.MjSpec) -> None:
        image = board.image(_TEXTURE_PX_PER_M)
        texture = spec.add_texture(name="calib_board", type=mujoco.mjtTexture.mjTEXTURE_2D,
                                   width=image.shape[1], height=image.shape[0], nchannel=3)
        texture.data = np.repeat(image[:, :, None], 3, axis=2).tobytes()
        material = spec.add_material(name="calib_board")
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "calib_board"
        # The texture's columns run along the plate's +x, its rows along -y (its top-left image
        # corner at (-w/2, +h/2)): the printed board's OpenCV frame (calib.board.board_on_table).
        half_thickness = board.thickness_m / 2
        body = spec.worldbody.add_body(name="calib_board", pos=[x_m, y_m, table_z_m + half_thickness],
                                       quat=[np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)])
        if movable:
            body.mocap = True
        width, height = board.size_m
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[width / 2, height / 2, half_thickness],
                      material="calib_board", contype=0, conaffinity=0)

    return add


def native_sizes(robot: Robot, cameras, image_size) -> dict[str, tuple[int, int]]:
    """Each camera's (height, width) in the take: ``image_size``; a camera with intrinsics keeps
    their aspect at that height (its intrinsics scale with it)."""
    height, width = int(image_size[0]), int(image_size[1])
    sizes = {}
    for cam in cameras:
        k = robot.rig[cam].intrinsics
        sizes[cam] = (height, int(round(k["width"] * height / k["height"]))) if k else (height, width)
    return sizes


def take_poses(robot: Robot, env: TabletopEnv, frames: int, spread_rad: float, rng: np.random.Generator,
               in_view) -> list[dict[str, np.ndarray]]:
    """Per frame, each arm's joint angles: home first, then home plus a uniform spread within the
    joints' limits; an arm that carries a camera keeps drawing (up to ``_TRIES`` times) until
    ``in_view(arm)`` says its cameras see the whole board, as an operator watching the feed would."""
    model = env.model
    poses = [{name: arm.home.copy() for name, arm in robot.arms.items()}]
    for _ in range(frames - 1):
        pose = {name: arm.home.copy() for name, arm in robot.arms.items()}
        for name, arm in robot.arms.items():
            for _ in range(_TRIES):
                q = arm.home + rng.uniform(-spread_rad, spread_rad, len(arm.joints))
                for i, joint in enumerate(arm.joints):
                    jid = model.joint(arm.named(joint)).id
                    if model.jnt_limited[jid]:
                        q[i] = np.clip(q[i], *model.jnt_range[jid])
                pose[name] = q
                env.pose_robot(robot.from_model({a: (p, 0.0) for a, p in pose.items()}))
                if in_view(name):
                    break
        poses.append(pose)
    return poses


def board_in_view(env: TabletopEnv, board: Board, T_world_from_board: np.ndarray, sizes: dict) -> callable:
    """``in_view(arm)``: every camera the arm carries sees the board's four corners in front of it."""
    width, height = board.size_m
    corners = (T_world_from_board @ np.array([[0, 0, 0, 1], [width, 0, 0, 1], [0, height, 0, 1],
                                              [width, height, 0, 1]], float).T).T[:, :3]

    def in_view(arm: str) -> bool:
        for cam, spec in env.robot.rig.items():
            if spec.arm != arm or cam not in sizes:
                continue
            h, w = sizes[cam]
            uv, depth = cam_geom.project_points(corners, env.camera_K(cam, (h, w)), env.camera_T_world_from_cam(cam))
            if np.any(depth <= 0.05) or np.any(uv < 0) or np.any(uv[:, 0] > w - 1) or np.any(uv[:, 1] > h - 1):
                return False
        return True

    return in_view


# ----------------------------------------------------------------------------- the lens take

GRIP_DEPTH_M = 0.02  # how far over the board's edge the jaws hold a carried board
# A board presented to a camera (held up to it, or the camera aimed at it): its corners span this
# share of the image (the tighter of width and height), so that at every placement they stay in
# the image and the ones nearest its borders fall in the border cells. Measured on the bundled
# head camera at 640 x 480 px: 0.55 leaves half the placements out of the arms' reach and the lens
# 0.2-0.3 px off, 0.75 reaches 79 of 81 and 0.1 px.
PRESENTED_FILL = 0.75
PRESENTED_MARGIN = 0.02  # its outermost corners this share of the image inside the borders
PRESENTED_PLACEMENTS = (0.0, 0.5, 1.0)  # where its corners sit in the range they can move in, per axis
# Tilts (about the camera's x and y axes) of a presented board: facing the camera and leaning
# 30 deg eight ways, far more than the lens fit's 5 deg apart.
_LEAN = np.deg2rad(30.0)
PRESENTED_TILTS = ((0.0, 0.0), (_LEAN, 0.0), (-_LEAN, 0.0), (0.0, _LEAN), (0.0, -_LEAN),
                   *((a * _LEAN / np.sqrt(2), b * _LEAN / np.sqrt(2)) for a in (1, -1) for b in (1, -1)))
TABLE_CLEARANCE_M = 0.02  # a presented board keeps this far above the table top
# The operator's coverage grid, finer than the lens fit's check (4 x 4): it keeps picking views
# that reach further into the image's borders and corners, where the distortion is largest.
COVERAGE_GRID = (8, 8)
ARM_CAMERA_DRAWS = 12  # arm poses drawn per frame of an arm's cameras' lens take, the best kept


@dataclass
class TakeFrame:
    """One frame of a lens take: each arm's joints and gripper closing, and the board: lying where
    stated (``carrier`` None) or held by ``carrier``'s gripper at ``T_site_from_board`` (its
    grasp-centre site's frame)."""

    joints: dict[str, np.ndarray]
    closing: dict[str, float] = field(default_factory=dict)
    carrier: str | None = None
    T_site_from_board: np.ndarray | None = None


def plate_from_board(board: Board) -> np.ndarray:
    """``T_board_from_plate``: the plate body's frame (centred, its face up along +z, as
    ``board_adder`` builds it) in the board's OpenCV frame (origin at the printed top-left corner,
    z into the board)."""
    width, height = board.size_m
    return poses.pose(np.diag([1.0, -1.0, -1.0]), (width / 2, height / 2, board.thickness_m / 2))


def edge_grips(board: Board) -> list[np.ndarray]:
    """``T_site_from_board`` of the board held by the middle of each of its four edges: the
    grasp-centre site's approach axis into the board along its face, the jaws closing on its
    thickness (site axes: approach, jaw, third; ``r2s_eval.sim.assembly.ee_site``)."""
    width, height = board.size_m
    centre = np.array([width / 2, height / 2, board.thickness_m / 2])
    grips = []
    for outward, half in (((0.0, 1.0), height / 2), ((0.0, -1.0), height / 2), ((1.0, 0.0), width / 2),
                          ((-1.0, 0.0), width / 2)):
        n = np.array([*outward, 0.0])
        z = np.array([0.0, 0.0, 1.0])
        board_axes = np.column_stack([n, np.cross(z, n), z])
        site_axes = np.column_stack([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
        R = site_axes @ board_axes.T  # the edge's outward normal against the approach, z along the jaws
        grips.append(poses.pose(R, -R @ (centre + (half - GRIP_DEPTH_M) * n)))
    return grips


def place_board(env: TabletopEnv, frame: TakeFrame, stated: np.ndarray, plate: np.ndarray) -> None:
    """Pose the robot as ``frame`` says and put the (mocap) board where it lies or is held."""
    robot = env.robot
    env.pose_robot(robot.from_model({a: (q, frame.closing.get(a, 0.0)) for a, q in frame.joints.items()}))
    T_world_from_board = stated
    if frame.carrier is not None:
        site = env.model.site(ee_site(frame.carrier)).id
        T_world_from_site = poses.pose(env.data.site_xmat[site].reshape(3, 3), env.data.site_xpos[site])
        T_world_from_board = T_world_from_site @ frame.T_site_from_board
    T = T_world_from_board @ plate
    mocap = env.model.body_mocapid[env.model.body("calib_board").id]
    env.data.mocap_pos[mocap] = T[:3, 3]
    mujoco.mju_mat2Quat(env.data.mocap_quat[mocap], T[:3, :3].ravel())
    mujoco.mj_kinematics(env.model, env.data)


def seen(env: TabletopEnv, board: Board, camera: str, size: tuple[int, int], min_corners: int) -> View | None:
    """The board as ``camera`` sees it now (its pinhole image, as the operator's feed shows it),
    or None where too few of its corners are found."""
    view = find_board(env.render(camera, size=size), board, env.camera_K(camera, size), 0, min_corners)
    return None if isinstance(view, str) else view


def most_coverage(candidates: list[tuple[object, dict[str, View]]], count: int,
                  sizes: dict[str, tuple[int, int]]) -> list[object]:
    """``count`` of the candidates (a pose and the views it gives, per camera), one at a time as
    an operator watching the feeds would pick: the most grid cells no pick covers yet, then the
    most cameras seeing a new tilt, then the most corners."""
    def cells(views: dict[str, View]) -> set:
        return {(cam, cell) for cam, view in views.items()
                for cell in grid_cells(view.corners_px, sizes[cam], COVERAGE_GRID)}

    covered: set = set()
    normals: dict[str, list[np.ndarray]] = {}
    pool, picks = list(candidates), []
    while pool and len(picks) < count:
        def gain(candidate):
            views = candidate[1]
            tilts = sum(new_tilt(view, normals.get(cam, [])) for cam, view in views.items())
            return len(cells(views) - covered), tilts, sum(len(view.ids) for view in views.values())
        best = pool.pop(max(range(len(pool)), key=lambda i: gain(pool[i])))
        picks.append(best[0])
        covered |= cells(best[1])
        for cam, view in best[1].items():
            if new_tilt(view, normals.get(cam, [])):
                normals.setdefault(cam, []).append(view.T_cam_from_board[:3, 2])
    return picks


def arm_camera_poses(env: TabletopEnv, board: Board, stated: np.ndarray, sizes: dict, frames: int,
                     spread_rad: float, rng: np.random.Generator, min_corners: int) -> list[dict[str, np.ndarray]]:
    """Per frame, each arm's joints for a lens take of the board lying where stated: home first,
    then for an arm carrying cameras the ``most_coverage`` of two kinds of pose: each camera
    aimed at the board (``aimed_poses``: the board over the image's placements and tilts) and
    ``ARM_CAMERA_DRAWS`` per frame drawn as ``take_poses`` draws them; an arm without cameras, or
    short of poses showing the board, stays home."""
    robot, model = env.robot, env.model
    home = {name: arm.home.copy() for name, arm in robot.arms.items()}
    plate = plate_from_board(board)
    chosen: dict[str, list[np.ndarray]] = {}
    for name, arm in robot.arms.items():
        cameras = [cam for cam, spec in robot.rig.items() if spec.arm == name and cam in sizes]
        if not cameras:
            continue
        poses_tried = [q for cam in cameras for q in aimed_poses(env, board, stated, cam, sizes[cam], name)]
        aimed = len(poses_tried)
        for _ in range(ARM_CAMERA_DRAWS * (frames - 1)):
            q = arm.home + rng.uniform(-spread_rad, spread_rad, len(arm.joints))
            for i, joint in enumerate(arm.joints):
                jid = model.joint(arm.named(joint)).id
                if model.jnt_limited[jid]:
                    q[i] = np.clip(q[i], *model.jnt_range[jid])
            poses_tried.append(q)
        candidates = []
        for k, q in enumerate(poses_tried):
            place_board(env, TakeFrame({**home, name: q}), stated, plate)
            views = {cam: view for cam in cameras
                     if (k < aimed or corners_may_show(env, board, stated, cam, sizes[cam], min_corners))
                     and (view := seen(env, board, cam, sizes[cam], min_corners)) is not None}
            if views:
                candidates.append((q, views))
        chosen[name] = most_coverage(candidates, frames - 1, sizes)
        log.info("board take: arm %s, %d aimed and %d drawn poses, %d show the board to %s; %d kept", name, aimed,
                 len(poses_tried) - aimed, len(candidates), cameras, len(chosen[name]))
    return [home] + [{name: (chosen[name][k] if k < len(chosen.get(name, [])) else home[name])
                      for name in robot.arms} for k in range(frames - 1)]


def corners_may_show(env: TabletopEnv, board: Board, T_world_from_board: np.ndarray, camera: str,
                     size: tuple[int, int], min_corners: int) -> bool:
    """Whether ``min_corners`` of the board's corners project into the camera's image in front of
    it, its face turned to the camera: worth rendering to look for the board."""
    h, w = size
    corners = board.corners_m(np.arange(board.n_corners))
    world = corners @ T_world_from_board[:3, :3].T + T_world_from_board[:3, 3]
    T_world_from_cam = env.camera_T_world_from_cam(camera)
    uv, depth = cam_geom.project_points(world, env.camera_K(camera, size), T_world_from_cam)
    facing = (T_world_from_board[:3, 3] - T_world_from_cam[:3, 3]) @ T_world_from_board[:3, 2] > 0
    inside = (depth > 0.05) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    return bool(facing and inside.sum() >= max(4, min_corners))


def presented_pose(board: Board, K: np.ndarray, size: tuple[int, int], tilt: tuple[float, float],
                   placement: tuple[float, float], turn_rad: float = 0.0) -> np.ndarray:
    """``T_cam_from_board`` of the board facing the camera (its columns along the image's rows,
    then turned by ``turn_rad`` about its normal), tilted by ``tilt`` (rad, about the camera's x
    and y) at the depth where its corners span ``PRESENTED_FILL`` of the image, moved parallel to
    the image until its corners sit at ``placement`` (0: by the left or top border, 1: by the
    right or bottom one, ``PRESENTED_MARGIN`` inside) of the range they can move in."""
    h, w = size
    width, height = board.size_m
    c, s = abs(np.cos(turn_rad)), abs(np.sin(turn_rad))
    depth = max(K[0, 0] * (c * width + s * height) / (PRESENTED_FILL * w),
                K[1, 1] * (s * width + c * height) / (PRESENTED_FILL * h))
    R = (cv2.Rodrigues(np.array([tilt[0], 0.0, 0.0]))[0] @ cv2.Rodrigues(np.array([0.0, tilt[1], 0.0]))[0]
         @ cv2.Rodrigues(np.array([0.0, 0.0, turn_rad]))[0])
    corners = board.corners_m(np.arange(board.n_corners))
    centre = np.array([width / 2, height / 2, 0.0])
    t = np.array([0.0, 0.0, depth]) - R @ centre
    margin = PRESENTED_MARGIN * np.array([w, h])
    for _ in range(3):  # the corners' extent changes a little as they move off the axis
        cam = corners @ R.T + t
        uv = (cam @ K.T)[:, :2] / cam[:, 2:3]
        low, high = uv.min(axis=0), uv.max(axis=0)
        target = margin + np.asarray(placement) * (np.array([w - 1, h - 1]) - 2 * margin - (high - low))
        t[:2] += (target - low) * (R @ centre + t)[2] / np.diag(K)[:2]
    return poses.pose(R, t)


def presented_poses(board: Board, K: np.ndarray, size: tuple[int, int], turn_rad: float = 0.0):
    """``presented_pose`` over ``PRESENTED_TILTS`` and the placements (``PRESENTED_PLACEMENTS``
    along each image axis)."""
    for tilt, placement in itertools.product(PRESENTED_TILTS, itertools.product(PRESENTED_PLACEMENTS, repeat=2)):
        yield presented_pose(board, K, size, tilt, placement, turn_rad)


PRESENTED_COUNT = len(PRESENTED_TILTS) * len(PRESENTED_PLACEMENTS) ** 2
AIMED_TURNS = (0.0, np.pi / 2, np.pi, -np.pi / 2)  # an arm's camera turned about its view of the board


def aimed_poses(env: TabletopEnv, board: Board, stated: np.ndarray, camera: str, size: tuple[int, int],
                arm: str) -> list[np.ndarray]:
    """``arm``'s joints that aim its ``camera`` at the board lying where stated, one per placement
    and tilt it reaches (``presented_poses``; the first turn about the view that inverse
    kinematics from home reaches with the camera above the table)."""
    robot = env.robot
    home = {name: a.home.copy() for name, a in robot.arms.items()}
    site = env.model.site(ee_site(arm)).id
    T_world_from_site = poses.pose(env.data.site_xmat[site].reshape(3, 3), env.data.site_xpos[site])
    T_site_from_cam = poses.inverse(T_world_from_site) @ env.camera_T_world_from_cam(camera)  # rigid on the arm
    ik, K = ArmIK(robot, arm, home), env.camera_K(camera, size)
    reached = []
    for by_turn in zip(*(presented_poses(board, K, size, turn) for turn in AIMED_TURNS)):
        for T_cam_from_board in by_turn:
            T_world_from_cam = stated @ poses.inverse(T_cam_from_board)
            if T_world_from_cam[2, 3] < robot.workspace_z_m + TABLE_CLEARANCE_M:
                continue
            T_world_from_site = T_world_from_cam @ poses.inverse(T_site_from_cam)
            q = ik.joints_for(T_world_from_site[:3, 3], T_world_from_site[:3, :3])
            if q is not None:
                reached.append(q)
                break
    return reached


def presentations(env: TabletopEnv, board: Board, camera: str, size: tuple[int, int], count: int,
                  min_corners: int, carriers: list[str] | None = None,
                  grips: list[np.ndarray] | None = None) -> list[TakeFrame]:
    """``count`` frames of an arm holding the board up to the fixed ``camera`` for its lens: over
    the placements and tilts (``presented_poses``), the first of the ``carriers`` (default: every
    arm) and ``grips`` (default: ``edge_grips``) that reach each (inverse kinematics from home)
    with the board above the table and seen whole enough (half its corners found), then the
    ``most_coverage`` of them."""
    robot = env.robot
    home = {name: arm.home.copy() for name, arm in robot.arms.items()}
    plate, grips = plate_from_board(board), edge_grips(board) if grips is None else grips
    K, T_world_from_cam = env.camera_K(camera, size), env.camera_T_world_from_cam(camera)
    iks = {name: ArmIK(robot, name, home) for name in robot.arms}
    closing = {name: float(np.clip(1.0 - board.thickness_m / 2 / arm.gripper.jaw_open_m, 0.0, 1.0))
               for name, arm in robot.arms.items()}  # the jaws on the plate
    width, height = board.size_m
    outline = np.array([[0.0, 0.0, 0.0], [width, 0.0, 0.0], [0.0, height, 0.0], [width, height, 0.0]])
    candidates = []
    for T_cam_from_board in presented_poses(board, K, size):
        T_world_from_board = T_world_from_cam @ T_cam_from_board
        lowest = (outline @ T_world_from_board[:3, :3].T + T_world_from_board[:3, 3])[:, 2].min()
        if lowest < robot.workspace_z_m + TABLE_CLEARANCE_M:
            continue
        for carrier, grip in itertools.product(carriers or list(robot.arms), grips):
            T_world_from_site = T_world_from_board @ poses.inverse(grip)
            q = iks[carrier].joints_for(T_world_from_site[:3, 3], T_world_from_site[:3, :3])
            if q is None:
                continue
            frame = TakeFrame({**home, carrier: q}, {carrier: closing[carrier]}, carrier, grip)
            place_board(env, frame, T_world_from_board, plate)
            view = seen(env, board, camera, size, max(min_corners, board.n_corners // 2))
            if view is not None:
                candidates.append((frame, {camera: view}))
                break
    picks = most_coverage(candidates, count, {camera: size})
    log.info("board take: %s, the board held up at %d of %d placements and tilts; %d kept", camera, len(candidates),
             PRESENTED_COUNT, len(picks))
    return picks


def lens_take_plan(env: TabletopEnv, board: Board, stated: np.ndarray, sizes: dict, take: dict,
                   rng: np.random.Generator, min_corners: int, mount: str = "table") -> list[TakeFrame]:
    """The frames of a take that also fits the lenses (module docstring): ``take["frames"]`` with
    the board lying where stated and the arms' cameras sweeping over it, then
    ``take["lens_frames"]`` of it held up to each fixed camera. A board carried by an arm
    (``mount``: its name) is held in one grip throughout, as the calibration finds one pose of it
    on the gripper: ``take["lens_frames"]`` frames held up to each fixed camera."""
    fixed = cam_geom.fixed_cameras(env.model, sizes)
    if mount != "table":
        if mount not in env.robot.arms or not fixed:
            raise ConfigError(f"calib.cameras.board.mount: {mount!r}: the twin carries the board in an arm of the "
                              f"robot {list(env.robot.arms)} up to the fixed cameras, and the take records "
                              f"{'no fixed camera' if fixed == [] else 'no such arm'}")
        grip = carried_grip(env, board, mount, {cam: sizes[cam] for cam in fixed})
        return [frame for cam in fixed for frame in presentations(env, board, cam, sizes[cam], int(take["lens_frames"]),
                                                                   min_corners, [mount], [grip])]
    frames = [TakeFrame(joints) for joints in arm_camera_poses(env, board, stated, sizes, int(take["frames"]),
                                                               float(take["joint_spread_rad"]), rng, min_corners)]
    for cam in fixed:
        frames += presentations(env, board, cam, sizes[cam], int(take["lens_frames"]), min_corners)
    return frames


def carried_grip(env: TabletopEnv, board: Board, carrier: str, sizes: dict) -> np.ndarray:
    """Of the ``edge_grips``, the one with which ``carrier`` reaches the most placements and tilts
    held up to the fixed cameras (``sizes``; inverse kinematics from home); the first on a tie."""
    robot = env.robot
    home = {name: arm.home.copy() for name, arm in robot.arms.items()}
    ik = ArmIK(robot, carrier, home)

    def reached(grip: np.ndarray) -> int:
        count = 0
        for cam, size in sizes.items():
            T_world_from_cam = env.camera_T_world_from_cam(cam)
            for T_cam_from_board in presented_poses(board, env.camera_K(cam, size), size):
                T_world_from_site = T_world_from_cam @ T_cam_from_board @ poses.inverse(grip)
                count += ik.joints_for(T_world_from_site[:3, 3], T_world_from_site[:3, :3]) is not None
        return count

    grips = edge_grips(board)
    return grips[int(np.argmax([reached(grip) for grip in grips]))]


def record_board_take(dataset: str, params: WorldParams, *, take: dict, board_cfg: dict, world: dict,
                      tasks: list[str], seed: int, reality: RealityEffects | None = None) -> dict:
    """Record the twin's board take into ``dataset``; returns what was recorded (frames, sizes).
    Every frame is recorded through the twin's camera (``reality``: its true lens, exposure and
    noise; None: the simulated camera).

    ``take``: ``teleop.board_take``; ``board_cfg``: ``calib.cameras.board`` (the board, its pose;
    with ``intrinsics`` the take also shows what the lens fit needs: ``lens_take_plan``);
    ``tasks``: the experiment's (the first one's scene holds the board; its objects are moved
    out of sight)."""
    robot = world_robot(world)
    board = Board.from_config(board_cfg)
    cameras = list(world["cameras"])
    sizes = native_sizes(robot, cameras, take["image_size"])
    pose = board_cfg["pose"]
    task = configured_task(tasks[0], world, None)
    largest = tuple(max(s[i] for s in sizes.values()) for i in (0, 1))
    lens_take = bool(board_cfg.get("intrinsics", False))  # a board config without the key fits no lens
    reality = reality or RealityEffects()
    # The twin's room around the board (its distractors lie beyond the table's far edge strip, clear
    # of the board's stated pose); the objects' own shapes go with them out of sight.
    model = build_model(robot, task.objects, params, largest,
                        scene_adder(reality, robot, task.objects, params,
                                    then=board_adder(board, float(pose["x_m"]), float(pose["y_m"]),
                                                     float(pose["yaw_rad"]), robot.workspace_z_m, movable=lens_take)))
    weaken_gripper(model, robot, reality.gripper_strength_scale)  # this twin's model, as RealityEnv builds it
    env = RealityEnv(task, params, reality, cameras=cameras, model=model, robot=robot)
    rng = np.random.default_rng([seed, 23])
    names = robot.feature_names
    frames = []
    try:
        env.reset(seed=int(rng.integers(2**31)), settle=False, observe=False)
        for name in task.object_names:  # out of sight, below the floor
            env.set_object_pose(name, (0.0, 0.0, -5.0), forward=False)
        stated = board_on_table(board, float(pose["x_m"]), float(pose["y_m"]), float(pose["yaw_rad"]), robot.workspace_z_m)
        if lens_take:
            plan = lens_take_plan(env, board, stated, sizes, take, rng, int(board_cfg["min_corners"]),
                                  str(board_cfg["mount"]))
        else:
            plan = [TakeFrame(joints) for joints in take_poses(robot, env, int(take["frames"]),
                                                               float(take["joint_spread_rad"]), rng,
                                                               board_in_view(env, board, stated, sizes))]
        plate = plate_from_board(board)
        for k, frame in enumerate(plan):
            closing = {a: frame.closing.get(a, 0.0) for a in frame.joints}
            if lens_take:
                place_board(env, frame, stated, plate)
            else:
                env.pose_robot(robot.from_model({a: (q, closing[a]) for a, q in frame.joints.items()}))
            env.steps = k  # keys this frame's encoder and image noise
            command = robot.from_model({a: (q - params.joint_offsets(a, len(q)), closing[a])
                                        for a, q in frame.joints.items()})
            obs = {"observation.state": env.state()}
            for cam in cameras:
                obs[f"observation.images.{cam}"] = env.render(cam, size=sizes[cam], add_noise=True)
            frames.append((obs, command))
    finally:
        env.close()
    features = lerobot_features(names, names, cameras, sizes)
    with DatasetRecorder(dataset, "local/board_take", round(robot.control_hz), features, robot.type,
                         video=take["video"]) as rec:
        rec.add_episode(frames, TAKE_TASK)
    log.info("board take: %d frames of %s", len(frames), {c: f"{w}x{h}" for c, (h, w) in sizes.items()})
    return {"frames": len(frames), "cameras": {c: list(s) for c, s in sizes.items()}}
