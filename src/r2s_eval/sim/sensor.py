"""What a world's camera adds to the pinhole image MuJoCo draws: its lens and its pixel noise.

``TabletopEnv.render(..., add_noise=True)`` (a world's observations, the judge videos, the board
take) records an image through ``recorded_image``: the pinhole render through the world's lens
(``WorldParams.lens_distortion``, the calibrated sim's answer to a lab camera's lens: OpenCV's
five coefficients as a board calibration fits them) and then the additive pixel noise
(``image_noise_std``, ``add_image_noise``); ``add_noise=False`` renders (the calibration's
hypotheses) stay clean pinhole images. A world without a lens records the pinhole image.

``undistorted`` is the way back: a recorded frame as the camera's pinhole would show it, which is
how the calibration compares a lab's frames with the calibrated sim's pinhole renders.

The same distortion maps draw the reality twin's own lens (``r2s_eval.twin.camera``: OpenCV's
rational model, eight coefficients), which is richer than any five-coefficient answer.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from r2s_eval.errors import ConfigError

DISTORTION_COEFFICIENTS = ("k1", "k2", "p1", "p2", "k3")  # OpenCV's order, the calibrated sim's lens
# OpenCV's rational model adds a radial denominator 1 + k4 r^2 + k5 r^4 + k6 r^6.
RATIONAL_COEFFICIENTS = (*DISTORTION_COEFFICIENTS, "k4", "k5", "k6")


# ----------------------------------------------------------------------------- noise


def add_image_noise(rgb: np.ndarray, rng: np.random.Generator, std: float) -> np.ndarray:
    """``rgb`` plus Gaussian noise of ``std`` drawn from ``rng``, clipped to [0, 255] and truncated
    to uint8 (``np.clip(rgb + noise, 0, 255).astype(np.uint8)``).

    The noise is drawn by inverse transform: a uniform 16-bit integer per value looked up in the
    standard normal's quantiles at the 65,536 midpoints (exactly Gaussian up to that resolution,
    tails cut at 4.3 sigma). Drawing them costs a fraction of ``rng.normal``'s ziggurat in
    float64: a 128 px image 0.5 against 1.15 CPU-ms, and the twin noises every image it records.
    """
    noisy = standard_normals(rng, rgb.shape)
    noisy *= std
    noisy += rgb
    np.clip(noisy, 0, 255, out=noisy)
    return noisy.astype(np.uint8)


def standard_normals(rng: np.random.Generator, shape) -> np.ndarray:
    """float32 standard normal values of ``shape`` drawn as ``add_image_noise`` draws them (one
    16-bit integer per value from ``rng``): a fresh array the caller may scale in place."""
    return _normal_quantiles()[rng.integers(0, 65536, shape, dtype=np.uint16)]


@functools.cache
def _normal_quantiles() -> np.ndarray:
    from scipy.special import ndtri

    return ndtri((np.arange(65536) + 0.5) / 65536).astype(np.float32)


# ----------------------------------------------------------------------------- lens


def distortion_maps(K: np.ndarray, coefficients, size_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel of the distorted image samples the pinhole image: cv2.remap's maps
    (fixed-point, ``CV_16SC2``) for a camera with intrinsics ``K`` (3x3, at ``size_hw``) and
    OpenCV distortion ``coefficients`` (k1, k2, p1, p2, k3, or the rational model's eight).

    The coefficients act on normalised coordinates (x / z, y / z), so one lens has the same
    coefficients at every resolution; only K scales with the image. A distorted pixel's source is
    the undistorted point it comes from (OpenCV's iterative undistortion, run to convergence):
    the inverse of what ``cv2.initUndistortRectifyMap`` maps, whose maps undistort. A pixel no
    point reaches (the polynomial folds back beyond the field its coefficients were fitted on)
    samples the pinhole image's edge along its own ray from the principal point.
    """
    import cv2

    coefficients = np.asarray(checked_coefficients(coefficients, len(coefficients)))
    h, w = int(size_hw[0]), int(size_hw[1])
    K = np.asarray(K, dtype=np.float64)
    centre, focal = K[:2, 2], np.diag(K)[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    distorted = np.stack([u.ravel(), v.ravel()], axis=-1)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    source = cv2.undistortPointsIter(distorted[:, None], K, coefficients, None, K, criteria).reshape(-1, 2)
    normalised = (source - centre) / focal
    back, _ = cv2.projectPoints(np.c_[normalised, np.ones(len(source))], np.zeros(3), np.zeros(3), K, coefficients)
    lost = ~np.all(np.isfinite(source), axis=1) | (np.linalg.norm(back.reshape(-1, 2) - distorted, axis=1) > 0.01)
    if lost.any():
        ray = distorted[lost] - centre
        with np.errstate(divide="ignore"):
            reach = np.min(np.where(ray > 0, (np.array([w - 1, h - 1]) - centre) / ray,
                                    np.where(ray < 0, -centre / ray, np.inf)), axis=1)
        source[lost] = centre + ray * reach[:, None]
    source = source.reshape(h, w, 2).astype(np.float32)
    return cv2.convertMaps(source[..., 0], source[..., 1], cv2.CV_16SC2)


def distort(rgb: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``rgb`` as the lens of ``maps`` (``distortion_maps``) shows it (bilinear).

    Where the distorted image looks past the pinhole image's border (the corners of a wide camera
    whose lens pulls them inwards), its edge pixels are repeated: a real sensor has pixels there
    that see the scene continuing, and black wedges would be an edge no lab camera records, a cue
    the policies and judges would see only in simulation."""
    import cv2

    return cv2.remap(rgb, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def through_lens(rgb: np.ndarray, K: np.ndarray, coefficients) -> np.ndarray:
    """``rgb`` (uint8[H, W, 3], a camera with intrinsics ``K`` at that size) through the lens of
    ``coefficients``; its maps are made once per camera, size and lens."""
    K = np.asarray(K, dtype=np.float64)
    key = tuple(float(c) for c in coefficients)
    return distort(rgb, _cached_maps(tuple(map(tuple, K)), key, rgb.shape[:2]))


def undistortion_maps(K: np.ndarray, coefficients, size_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel of the pinhole image samples the distorted one: cv2.remap's maps
    (``CV_16SC2``, ``cv2.initUndistortRectifyMap`` with the same ``K`` before and after) for a
    camera with intrinsics ``K`` (3x3, at ``size_hw``) and OpenCV distortion ``coefficients``
    (five, or the rational model's eight): the inverse of ``distortion_maps``."""
    import cv2

    coefficients = np.asarray(checked_coefficients(coefficients, len(coefficients)))
    h, w = int(size_hw[0]), int(size_hw[1])
    K = np.asarray(K, dtype=np.float64)
    return cv2.initUndistortRectifyMap(K, coefficients, None, K, (w, h), cv2.CV_16SC2)


def undistorted(rgb: np.ndarray, K: np.ndarray, coefficients) -> np.ndarray:
    """``rgb`` (a frame recorded through the lens of ``coefficients``, a camera with intrinsics ``K``
    at that size) as the camera's pinhole would show it: ``cv2.undistort`` with ``K`` kept
    (bilinear), its maps made once per camera, size and lens. Where the pinhole image looks past
    what the lens recorded (the corners of a pincushion lens), the frame's edge is repeated
    (``undistorted_coverage`` says where). A pinhole lens (``is_pinhole``) returns ``rgb`` itself.

    The calibration's steps that compare a recorded frame with the calibrated sim's pinhole
    renders see the frame through this (``r2s_eval.calib.scene.pinhole_frame``)."""
    import cv2

    if is_pinhole(coefficients):
        return rgb
    maps = _cached_undistortion_maps(_K_key(K), tuple(float(c) for c in coefficients), tuple(rgb.shape[:2]))
    return cv2.remap(rgb, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def undistorted_coverage(K: np.ndarray, coefficients, size_hw: tuple[int, int]) -> np.ndarray:
    """bool[H, W]: the pixels of ``undistorted``'s image that the recorded frame covers (their
    source lies inside it); all of them for a pinhole lens."""
    import cv2

    size_hw = (int(size_hw[0]), int(size_hw[1]))
    if is_pinhole(coefficients):
        return np.ones(size_hw, bool)
    maps = _cached_undistortion_maps(_K_key(K), tuple(float(c) for c in coefficients), size_hw)
    ones = np.full(size_hw, 255, np.uint8)
    return cv2.remap(ones, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=0) == 255


def _K_key(K: np.ndarray) -> tuple:
    return tuple(map(tuple, np.asarray(K, dtype=np.float64)))


@functools.lru_cache(maxsize=64)
def _cached_undistortion_maps(K_rows: tuple, coefficients: tuple, size_hw: tuple[int, int]):
    return undistortion_maps(np.asarray(K_rows), coefficients, size_hw)


def is_pinhole(coefficients) -> bool:
    """Whether a lens's coefficients are all zero: such a lens records the pinhole image's bytes."""
    return coefficients is None or not any(coefficients)


@functools.lru_cache(maxsize=64)
def _cached_maps(K_rows: tuple, coefficients: tuple, size_hw: tuple[int, int]):
    return distortion_maps(np.asarray(K_rows), coefficients, size_hw)


def checked_coefficients(coefficients, count: int = len(DISTORTION_COEFFICIENTS)) -> tuple[float, ...]:
    """``coefficients`` as floats: ``count`` finite ones, five (the calibrated sim's lens) or
    eight (OpenCV's rational model); else a ConfigError naming what was given."""
    values = tuple(float(c) for c in coefficients)
    names = {5: DISTORTION_COEFFICIENTS, 8: RATIONAL_COEFFICIENTS}.get(count)
    if names is None or len(values) != count or not all(math.isfinite(c) for c in values):
        expected = names or DISTORTION_COEFFICIENTS
        raise ConfigError(f"lens distortion {tuple(coefficients)!r}: {len(expected)} finite coefficients {expected}")
    return values
