"""Camera geometry: intrinsics, OpenCV-convention extrinsics, projection.

Conventions
-----------
* MuJoCo cameras look along their local -z with x right and y up.
* Everything exported here uses the OpenCV camera frame: x right, y down,
  z forward (optical axis). ``T_world_from_cam`` maps homogeneous points in
  that camera frame to world coordinates (metres).
* Pixel coordinates (u, v) follow OpenCV too: u = column, v = row, and the
  centre of pixel (row r, column c) is at (u, v) = (c, r). Hence
  cx = (W - 1) / 2 and cy = (H - 1) / 2.
* MuJoCo's ``fovy`` is the vertical field of view; pixels are square, so
  fx = fy = (H / 2) / tan(fovy / 2).
"""

from __future__ import annotations

import mujoco
import numpy as np

from r2s_eval.sim.rotations import matrix_from_quat, quat_from_matrix, rotvec_from_matrix

# MuJoCo camera axes -> OpenCV camera axes (flip y and z).
_R_MJCAM_FROM_CV = np.diag([1.0, -1.0, -1.0])


def intrinsics_K(fovy_deg: float, height_px: int, width_px: int) -> np.ndarray:
    """3x3 pinhole matrix for a MuJoCo camera rendered at (height_px, width_px)."""
    f_px = 0.5 * height_px / np.tan(0.5 * np.deg2rad(fovy_deg))
    return np.array(
        [[f_px, 0.0, (width_px - 1) / 2.0], [0.0, f_px, (height_px - 1) / 2.0], [0.0, 0.0, 1.0]]
    )


def model_K(model: mujoco.MjModel, camera: str, height_px: int, width_px: int) -> np.ndarray:
    """3x3 pinhole matrix of a model's camera rendered at (height_px, width_px): from its
    intrinsics where it has them (focal length and principal point on a sensor), else its fovy."""
    cam = model.camera(camera).id
    sensor_w, sensor_h = model.cam_sensorsize[cam]
    if sensor_h <= 0:
        return intrinsics_K(float(model.cam_fovy[cam]), height_px, width_px)
    fx, fy, px, py = model.cam_intrinsic[cam]
    # MuJoCo's principal point is an offset from the sensor centre, positive left and up.
    return np.array([
        [fx / sensor_w * width_px, 0.0, (width_px - 1) / 2.0 - px / sensor_w * width_px],
        [0.0, fy / sensor_h * height_px, (height_px - 1) / 2.0 - py / sensor_h * height_px],
        [0.0, 0.0, 1.0],
    ])


def T_world_from_cam(model: mujoco.MjModel, data: mujoco.MjData, camera: str) -> np.ndarray:
    """4x4 pose of the camera (OpenCV frame) in the world, from current kinematics."""
    cam_id = model.camera(camera).id
    R_world_from_mjcam = data.cam_xmat[cam_id].reshape(3, 3)
    T = np.eye(4)
    T[:3, :3] = R_world_from_mjcam @ _R_MJCAM_FROM_CV
    T[:3, 3] = data.cam_xpos[cam_id]
    return T


def T_parent_from_cam(pos_m, quat_wxyz) -> np.ndarray:
    """4x4 pose of the OpenCV camera frame in the camera's parent body frame, from the MuJoCo
    camera's ``pos``/``quat`` there."""
    T = np.eye(4)
    T[:3, :3] = matrix_from_quat(quat_wxyz) @ _R_MJCAM_FROM_CV
    T[:3, 3] = pos_m
    return T


def mount_error(pos_m, quat_wxyz, T_parent_from_cam_cv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mount error (position and rotation vector, in the nominal MuJoCo camera's own frame:
    ``WorldParams.camera_pos_offset_m`` / ``camera_rot_offset_rad``) that moves a camera at
    ``pos_m``/``quat_wxyz`` (its parent's frame) to the pose ``T_parent_from_cam_cv``."""
    R_nominal = matrix_from_quat(quat_wxyz)
    R_found = np.asarray(T_parent_from_cam_cv)[:3, :3] @ _R_MJCAM_FROM_CV.T
    dpos = R_nominal.T @ (np.asarray(T_parent_from_cam_cv)[:3, 3] - np.asarray(pos_m, float))
    return dpos, rotvec_from_matrix(R_nominal.T @ R_found)


def project_points(
    points_world_m: np.ndarray, K: np.ndarray, T_world_from_cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Project (N, 3) world points; returns (N, 2) pixel (u, v) and (N,) depth along z_cam (m)."""
    pts = np.atleast_2d(np.asarray(points_world_m, dtype=float))
    T_cam_from_world = np.linalg.inv(T_world_from_cam)
    pts_cam = pts @ T_cam_from_world[:3, :3].T + T_cam_from_world[:3, 3]
    depth_m = pts_cam[:, 2]
    uv = (pts_cam @ K.T)[:, :2] / depth_m[:, None]
    return uv, depth_m


def backproject_pixels(
    uv_px: np.ndarray, depth_m: np.ndarray, K: np.ndarray, T_world_from_cam: np.ndarray
) -> np.ndarray:
    """Inverse of ``project_points``: (N, 2) pixels + (N,) z-depth -> (N, 3) world points."""
    uv = np.atleast_2d(np.asarray(uv_px, dtype=float))
    depth = np.asarray(depth_m, dtype=float).reshape(-1)
    rays_cam = np.c_[uv, np.ones(len(uv))] @ np.linalg.inv(K).T
    pts_cam = rays_cam * depth[:, None]
    return pts_cam @ T_world_from_cam[:3, :3].T + T_world_from_cam[:3, 3]


def look_at_quat_wxyz(pos_m: np.ndarray, target_m: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Orientation (wxyz) of a MuJoCo camera at ``pos_m`` looking at ``target_m``."""
    forward = np.asarray(target_m, float) - np.asarray(pos_m, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    z_axis = -forward  # MuJoCo cameras look along -z
    y_axis = np.cross(z_axis, right)
    R = np.column_stack([right, y_axis, z_axis])
    return quat_from_matrix(R)


def fixed_cameras(model, cameras) -> list:
    """The cameras of ``cameras`` mounted on no arm: their body is welded to the world."""
    return [c for c in cameras if model.body_weldid[model.cam_bodyid[model.camera(c).id]] == 0]
