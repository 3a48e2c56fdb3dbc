"""Rotations the way MuJoCo writes them: unit quaternions (w, x, y, z) and 3x3 matrices.

The one owner of the conversions the scene assembly, the cameras and the objects need, all done
by MuJoCo's own routines so a pose means the same everywhere in the simulator.
"""

from __future__ import annotations

import mujoco
import numpy as np


def quat_from_matrix(R) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(R, float).flatten())
    return quat


def matrix_from_quat(quat) -> np.ndarray:
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat, float))
    return R.reshape(3, 3)


def quat_multiply(a, b) -> np.ndarray:
    """The rotation ``b`` followed by ``a`` (``a * b``)."""
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, float), np.asarray(b, float))
    return out


def yaw_quat(yaw_rad: float) -> np.ndarray:
    """Rotation about world z by ``yaw_rad``."""
    return np.array([np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)])


def euler_quat(euler_rad, axes: str = "xyz") -> np.ndarray:
    """Rotation of Euler angles (radians) about ``axes``, as MuJoCo's ``euler`` attribute reads them."""
    quat = np.zeros(4)
    mujoco.mju_euler2Quat(quat, np.asarray(euler_rad, float), axes)
    return quat


def rotvec_quat(rotvec) -> np.ndarray:
    """Rotation of a rotation vector (axis times angle, radians)."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    quat = np.zeros(4)
    mujoco.mju_axisAngle2Quat(quat, rotvec / angle, angle)
    return quat


def rotvec_from_matrix(R) -> np.ndarray:
    """Rotation vector (axis times angle, radians) of a rotation matrix; the inverse of
    ``rotvec_quat`` followed by ``matrix_from_quat``."""
    rotvec = np.zeros(3)
    mujoco.mju_quat2Vel(rotvec, quat_from_matrix(R), 1.0)
    return rotvec
