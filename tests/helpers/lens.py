"""A straight line drawn through a lens by the sim's distortion maps, for the lens tests."""

from __future__ import annotations

import cv2
import numpy as np

from r2s_eval.sim.sensor import distort, distortion_maps
from tests.helpers.worlds import bundled_env

LINE_Y = -0.6  # normalised: a horizontal line in the image's upper part
LINE_X = np.linspace(-0.9, 0.9, 19)  # the wrist camera's 75 deg: the line runs out to x / z = +-0.9


def wrist_K(size: tuple[int, int]) -> np.ndarray:
    env = bundled_env("cup_on_plate", cameras=())
    try:
        return env.camera_K("wrist_left", size)
    finally:
        env.close()


def project(K: np.ndarray, coefficients, rays: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of normalised rays (N, 2) through OpenCV's model with ``coefficients``."""
    points = np.c_[rays, np.ones(len(rays))]
    pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, np.asarray(coefficients, dtype=float))
    return pixels.reshape(-1, 2)


def line_through_lens(coefficients, size: tuple[int, int] = (480, 640)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The line at ``LINE_Y`` drawn in a pinhole image of the wrist camera and distorted with
    ``coefficients``: (K, where OpenCV's projection puts its points at ``LINE_X`` (N, 2 pixels),
    the row of the drawn line's centroid found at each of those columns (N,))."""
    K = wrist_K(size)
    rows = np.arange(size[0], dtype=float)[:, None]
    v_line = K[1, 2] + LINE_Y * K[1, 1]
    profile = 255 * np.exp(-((rows - v_line) ** 2) / (2 * 1.5**2))  # a smooth line: its centroid is exact
    pinhole = np.repeat(np.round(np.broadcast_to(profile, size)).astype(np.uint8)[:, :, None], 3, axis=2)
    distorted = distort(pinhole, distortion_maps(K, coefficients, size))
    predicted = project(K, coefficients, np.c_[LINE_X, np.full_like(LINE_X, LINE_Y)])
    measured = []
    for u, v in predicted:
        column = distorted[:, int(round(u)), 0].astype(float)
        near = slice(int(v) - 8, int(v) + 9)
        measured.append((column[near] * rows[near, 0]).sum() / column[near].sum())
    return K, predicted, np.asarray(measured)
