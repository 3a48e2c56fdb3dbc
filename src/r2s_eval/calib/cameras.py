"""The calibrated sim's camera poses: from a board take (``calibrate_from_board``), read back as
world parameters (``camera_params``), and scored against a known truth (``camera_errors``).

An estimate is stored as each camera's mount error against the model's nominal pose, in the
camera's own frame (``WorldParams.camera_pos_offset_m`` / ``camera_rot_offset_rad``): what the
twin perturbs, and what replay, rollouts and the initial-pose estimate build their cameras with.
The robot-silhouette estimate (``r2s_eval.calib.silhouette``) writes the same record.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping, Sequence

import numpy as np

from r2s_eval.calib import poses
from r2s_eval.calib.board import Board, CameraFit, board_on_table, find_board, fit_camera
from r2s_eval.calib.take import read_take
from r2s_eval.errors import ConfigError
from r2s_eval.sim import TabletopEnv, WorldParams
from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.assembly import ee_site
from r2s_eval.sim.build import make_env
from r2s_eval.sim.render_params import mounted_pose
from r2s_eval.sim.robot import world_robot
from r2s_eval.utils.io import read_json

log = logging.getLogger("r2s_eval.calib_cameras")


def nominal_env(world: Mapping, tasks: Sequence[str]) -> TabletopEnv:
    """The calibrated sim before its cameras are calibrated (the first task's scene, objects
    aside): its kinematics and its cameras' nominal mounts."""
    return make_env(tasks[0], world, WorldParams(), cameras=())


def body_pose(env: TabletopEnv, body: int) -> np.ndarray:
    return poses.pose(env.data.xmat[body].reshape(3, 3), env.data.xpos[body])


def camera_record(env: TabletopEnv, camera: str, T_parent_from_cam: np.ndarray) -> dict:
    """The mount error that puts ``camera`` at ``T_parent_from_cam`` (OpenCV frame, parent body)."""
    cid = env.model.camera(camera).id
    dpos, drot = cam_geom.mount_error(env.model.cam_pos[cid], env.model.cam_quat[cid], T_parent_from_cam)
    return {"pos_offset_m": [float(v) for v in dpos], "rot_offset_rad": [float(v) for v in drot]}


def calibrate_from_board(take_path: str, world: Mapping, board_cfg: Mapping, tasks: Sequence[str]) -> dict:
    """Every recorded camera's pose from the board take at ``take_path`` (``r2s_eval.calib.take``);
    ``board_cfg``: ``calib.cameras.board``. A camera whose frames show too little of the board is
    an error naming the frames left out and why."""
    robot = world_robot(world)
    board = Board.from_config(board_cfg)
    cameras = list(world["cameras"])
    take = read_take(take_path, cameras, robot.feature_names)
    env = nominal_env(world, tasks)
    min_corners, min_frames = int(board_cfg["min_corners"]), int(board_cfg["min_frames"])
    mount = board_cfg["mount"]
    try:
        if mount != "table" and mount not in robot.arms:
            raise ConfigError(f"calib.cameras.board.mount: 'table' or an arm of the robot {list(robot.arms)}, "
                              f"got {mount!r}")
        holder = None if mount == "table" else int(env.model.site_bodyid[env.model.site(ee_site(mount)).id])
        parents = {cam: int(env.model.cam_bodyid[env.model.camera(cam).id]) for cam in cameras}
        world_poses: dict[int, dict[int, np.ndarray]] = {}  # frame -> body -> T_world_from_body
        for frame, state in enumerate(take.states):
            env.pose_robot(state)
            world_poses[frame] = {b: body_pose(env, b) for b in {*parents.values(), holder or 0}}
        pose = board_cfg["pose"]
        stated = (board_on_table(board, float(pose["x_m"]), float(pose["y_m"]), float(pose["yaw_rad"]),
                                 robot.workspace_z_m) if mount == "table" else None)
        out = {}
        for cam in cameras:
            images = take.images[cam]
            K = env.camera_K(cam, images[0].shape[:2])
            views, left_out = [], {}
            for frame, image in enumerate(images):
                found = find_board(image, board, K, frame, min_corners)
                if isinstance(found, str):
                    left_out[frame] = found
                else:
                    views.append(found)
            parent_poses = {f: world_poses[f][parents[cam]] for f in world_poses}
            holder_poses = {f: world_poses[f][holder or 0] for f in world_poses}
            fitted = functools.partial(fit_camera, views, K, board, parent_poses, holder_poses, stated,
                                       min_frames=min_frames, max_rms_px=float(board_cfg["max_reprojection_px"]),
                                       where=f"board take {take_path}, camera {cam}", left_out=left_out)
            # A board on the table: every camera takes its stated pose (as the fixed ones must). A
            # camera on an arm also finds where the board lies (slid and turned on the table from
            # the statement), which says how far off the statement is. A carried board: found.
            fit = fitted("free" if stated is None else "fixed")
            found = fitted("planar") if stated is not None and env.model.body_weldid[parents[cam]] != 0 else None
            out[cam] = {**camera_record(env, cam, fit.T_parent_from_cam), **_fit_record(fit, stated, found)}
            log.info("%s: %d frames, reprojection %.2f px, standard error %.2f mm / %.3f deg; %d frames left out",
                     cam, len(fit.frames_used), fit.rms_px, fit.std_position_mm, fit.std_rotation_deg,
                     len(fit.frames_left_out))
            for frame, why in sorted(fit.frames_left_out.items()):
                log.info("%s: frame %d left out: %s", cam, frame, why)
    finally:
        env.close()
    return {"method": "board", "take": str(take_path), "frames": len(take.states), "cameras": out}


def _fit_record(fit: CameraFit, stated: np.ndarray | None, found: CameraFit | None) -> dict:
    record = {"frames_used": fit.frames_used,
              "frames_left_out": {str(f): why for f, why in sorted(fit.frames_left_out.items())},
              "reprojection_px": fit.rms_px, "std_position_mm": fit.std_position_mm,
              "std_rotation_deg": fit.std_rotation_deg}
    if found is not None:  # the board's pose the views give against the lab's statement
        mm, deg = poses.distance(found.T_mount_from_board, stated)
        record["board_from_stated"] = {"mm": mm, "deg": deg}
    return record


def camera_params(record: Mapping | None) -> dict:
    """``WorldParams`` fields of a cameras record (``{"cameras": {cam: {pos_offset_m, ...}}}``);
    None: the nominal cameras."""
    cams = (record or {}).get("cameras") or {}
    return {"camera_pos_offset_m": {c: tuple(v["pos_offset_m"]) for c, v in cams.items()},
            "camera_rot_offset_rad": {c: tuple(v["rot_offset_rad"]) for c, v in cams.items()}}


def calibrated_cameras(path: str | None) -> WorldParams:
    """World parameters holding the cameras of a cameras record file (None: the model's)."""
    return WorldParams(**camera_params(read_json(path) if path else None))


def camera_errors(estimated: WorldParams, truth: WorldParams, world: Mapping, tasks: Sequence[str],
                  cameras: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per camera, how far the estimated pose is from the true one: position (mm) and angle (deg),
    in the camera's parent frame (a wrist camera: on its link)."""
    env = nominal_env(world, tasks)
    try:
        out = {}
        for cam in cameras:
            cid = env.model.camera(cam).id
            placed = [cam_geom.T_parent_from_cam(*mounted_pose(
                env.model.cam_pos[cid], env.model.cam_quat[cid], params.camera_pos_offset_m.get(cam, (0.0, 0.0, 0.0)),
                params.camera_rot_offset_rad.get(cam, (0.0, 0.0, 0.0)))) for params in (estimated, truth)]
            mm, deg = poses.distance(*placed)
            out[cam] = {"position_mm": mm, "rotation_deg": deg}
        return out
    finally:
        env.close()


def score_calibration(estimates: Mapping[str, dict], calibrated: Mapping, truth: WorldParams, world: Mapping,
                      tasks: Sequence[str]) -> dict:
    """Each camera estimate (``{method: cameras record}``) and the model's own poses against the
    twin's true cameras, which estimate the calibrated sim (``calibrated``: its world parameters
    file) used, and its appearance fit's colour error before and after."""
    cameras = sorted({c for record in estimates.values() for c in record["cameras"]}) or list(world["cameras"])
    scored = {"model": camera_errors(WorldParams(), truth, world, tasks, cameras)}
    for method, record in estimates.items():
        scored[method] = camera_errors(WorldParams(**camera_params(record)), truth, world, tasks, list(record["cameras"]))
    appearance = calibrated.get("appearance") or {}
    return {"cameras": scored, "used": (calibrated.get("cameras") or {}).get("method", "none"),
            "appearance": {k: appearance.get(k) for k in ("fitted", "residual_before", "residual_after")}}

