"""Rigid poses as 4x4 matrices: to and from a 6-vector, their mean, and the distance of two.

A pose ``T_a_from_b`` maps points in frame b to frame a. The 6-vector is (rotation vector (rad),
translation (m)), what the calibration's least-squares fits move.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from r2s_eval.sim.rotations import matrix_from_quat, rotvec_from_matrix, rotvec_quat


def pose(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, float).reshape(3)
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    return pose(R.T, -R.T @ t)


def from_vector(v) -> np.ndarray:
    v = np.asarray(v, float)
    return pose(matrix_from_quat(rotvec_quat(v[:3])), v[3:])


def to_vector(T: np.ndarray) -> np.ndarray:
    return np.r_[rotvec_from_matrix(T[:3, :3]), T[:3, 3]]


def mean_pose(poses: Sequence[np.ndarray]) -> np.ndarray:
    """The translation mean and the rotation closest (chordal) to the rotations' mean."""
    U, _, Vt = np.linalg.svd(np.sum([T[:3, :3] for T in poses], axis=0))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return pose(R, np.mean([T[:3, 3] for T in poses], axis=0))


def distance(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(position distance in mm, rotation angle between them in degrees)."""
    dR = T_a[:3, :3].T @ T_b[:3, :3]
    angle = np.arccos(np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0))
    return float(1000.0 * np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])), float(np.rad2deg(angle))
