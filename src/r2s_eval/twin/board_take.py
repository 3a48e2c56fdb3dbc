"""The twin's board take: a ChArUco board lying on the table, the arms moving through poses, every
recorded camera at its native resolution, recorded as a lab records one (a LeRobotDataset v3 of
one episode: joint states as the encoders read them, the commands, one video per camera).

The board is printed from ``cv2.aruco`` onto a thin plate at the pose the calibration config
states (``calib.cameras.board.pose``): the lab's statement is exact here. The arms hold each
pose still (a frame per pose), so a frame is the kinematics of the twin's true joint angles: the
first frame at home, then each arm's joints spread uniformly around home within their limits,
drawn again until the cameras the arm carries see the whole board.
"""

from __future__ import annotations

import logging

import mujoco
import numpy as np

from r2s_eval.calib.board import Board, board_on_table
from r2s_eval.data import DatasetRecorder, lerobot_features
from r2s_eval.sim import TabletopEnv, WorldParams
from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.assembly import build_model
from r2s_eval.sim.build import configured_task
from r2s_eval.sim.robot import Robot, world_robot

log = logging.getLogger("r2s_eval.board_take")

TAKE_TASK = "ChArUco board take"
_TRIES = 200  # draws per arm and frame before a pose that does not show the board is kept
_TEXTURE_PX_PER_M = 5000  # 0.2 mm per texel: finer than any camera here resolves


def board_adder(board: Board, x_m: float, y_m: float, yaw_rad: float, table_z_m: float):
    """A function adding the printed board on a thin plate lying on the table (no contacts)."""

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


def record_board_take(dataset: str, params: WorldParams, *, take: dict, board_cfg: dict, world: dict,
                      tasks: list[str], seed: int) -> dict:
    """Record the twin's board take into ``dataset``; returns what was recorded (frames, sizes).

    ``take``: ``teleop.board_take``; ``board_cfg``: ``calib.cameras.board`` (the board, its pose);
    ``tasks``: the experiment's (the first one's scene holds the board; its objects are moved
    out of sight)."""
    robot = world_robot(world)
    board = Board.from_config(board_cfg)
    cameras = list(world["cameras"])
    sizes = native_sizes(robot, cameras, take["image_size"])
    pose = board_cfg["pose"]
    task = configured_task(tasks[0], world, None)
    largest = tuple(max(s[i] for s in sizes.values()) for i in (0, 1))
    model = build_model(robot, task.objects, params, largest,
                        board_adder(board, float(pose["x_m"]), float(pose["y_m"]), float(pose["yaw_rad"]),
                                    robot.workspace_z_m))
    env = TabletopEnv(task, params, cameras=cameras, model=model, robot=robot)
    rng = np.random.default_rng([seed, 23])
    names = robot.feature_names
    frames = []
    try:
        env.reset(seed=int(rng.integers(2**31)), settle=False, observe=False)
        for name in task.object_names:  # out of sight, below the floor
            env.set_object_pose(name, (0.0, 0.0, -5.0), forward=False)
        stated = board_on_table(board, float(pose["x_m"]), float(pose["y_m"]), float(pose["yaw_rad"]), robot.workspace_z_m)
        in_view = board_in_view(env, board, stated, sizes)
        for k, joints in enumerate(take_poses(robot, env, int(take["frames"]), float(take["joint_spread_rad"]), rng,
                                              in_view)):
            true_state = robot.from_model({a: (q, 0.0) for a, q in joints.items()})
            env.pose_robot(true_state)
            env.steps = k  # keys this frame's encoder and image noise
            command = robot.from_model({a: (q - params.joint_offsets(a, len(q)), 0.0) for a, q in joints.items()})
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
