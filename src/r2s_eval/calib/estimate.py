"""Initial object poses from one calibrated camera frame.

1. segment each object and take its silhouette centroid and principal axis;
2. back-project the centroid ray onto the horizontal plane at the object's centroid height
   (calibrated intrinsics K and extrinsics T_world_from_cam);
3. refine: render the simulator at the estimate from the same calibrated camera and move each
   object until its rendered centroid lands on the observed one (Gauss-Newton on the pixel
   reprojection error; with ``match="overlap"`` until the rendered silhouette needs no shift to
   lie over the observed one with the largest overlap, which a part of the object the model
   lacks, a mug's handle, pulls far less). This removes the perspective bias of step 2 (a
   silhouette centroid is not the projection of the 3-D centre) and absorbs the object's shape.
   For objects whose yaw is observable (``yaw_symmetry`` > 0) the yaw is then searched over one
   symmetry period (a coarse grid, then a finer one around the best) for the rendering that best
   matches the frame: with ``render_image``, the normalised cross-correlation of the luminance
   around the object (maximised over sub-pixel shifts; with ``appearance_window="object"`` over
   the object's own pixels only); otherwise the overlap (IoU) of the silhouettes.
   Luminance is what survives video compression at full resolution (4:2:0 chroma is halved,
   which blurs colour masks of small objects), and it shows inner edges such as a block's
   top face. Then the position is refined again;
4. add the per-task offsets fitted on calibration episodes (``fit_offsets``).
Poses are planar: (x_m, y_m) of the object's bottom centre in the world frame, and yaw_rad.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from r2s_eval.calib.segment import Segmenter
from r2s_eval.errors import EstimationError

# rendered masks for a set of planar poses {name: (x_m, y_m, yaw_rad)}
RenderMasks = Callable[[dict[str, tuple[float, float, float]]], dict[str, np.ndarray]]
# rendered RGB image (uint8 HxWx3) for a set of planar poses, same camera
RenderImage = Callable[[dict[str, tuple[float, float, float]]], np.ndarray]

APPEARANCE_PAD_PX = 3  # window margin around the object, and the largest shift searched
APPEARANCE_UPSAMPLE = 4  # sub-pixel shifts: both windows are upsampled before matching
OVERLAP_SHIFT_PX = 4  # match="overlap": the largest shift searched per iteration (px)
OVERLAP_BLUR_PX = 1.0  # and the Gaussian both masks are blurred by before they are correlated
OVERLAP_UPSAMPLE = 4
MATCHES = ("centroid", "overlap")
APPEARANCE_WINDOWS = ("box", "object")


class InitEstimationError(EstimationError):
    """An object could not be located; the message names it (and the episode, via the caller)."""


@dataclass(frozen=True)
class CameraModel:
    K: np.ndarray  # 3x3 pinhole intrinsics, pixels
    T_world_from_cam: np.ndarray  # 4x4, OpenCV camera frame (x right, y down, z forward)

    def project(self, points_world_m: np.ndarray) -> np.ndarray:
        pts = np.atleast_2d(points_world_m)
        T_cam_from_world = np.linalg.inv(self.T_world_from_cam)
        pts_cam = pts @ T_cam_from_world[:3, :3].T + T_cam_from_world[:3, 3]
        uv = pts_cam @ self.K.T
        return uv[:, :2] / uv[:, 2:3]

    def backproject_to_plane(self, uv_px: Sequence[float], plane_z_m: float) -> np.ndarray:
        """World point where the pixel's viewing ray meets the plane z = plane_z_m."""
        ray_cam = np.linalg.solve(self.K, np.array([uv_px[0], uv_px[1], 1.0]))
        ray_world = self.T_world_from_cam[:3, :3] @ ray_cam
        origin = self.T_world_from_cam[:3, 3]
        if abs(ray_world[2]) < 1e-9:
            raise InitEstimationError(f"pixel {tuple(uv_px)} looks parallel to the table plane")
        t = (plane_z_m - origin[2]) / ray_world[2]
        if t <= 0:
            raise InitEstimationError(f"pixel {tuple(uv_px)} does not look down at the table plane")
        return origin + t * ray_world


@dataclass(frozen=True)
class ObjectGeometry:
    name: str
    centroid_height_m: float  # height above the table of the silhouette's 3-D centre (approx.)
    yaw_symmetry: int = 0  # n-fold symmetry about z; 0 = rotationally symmetric (yaw unobservable)


@dataclass
class PoseEstimate:
    name: str
    x_m: float
    y_m: float
    yaw_rad: float
    reproj_error_px: float  # centroid distance after refinement (nan if not refined)
    iterations: int
    mask_area_px: int


def _centroid_and_axis(mask: np.ndarray) -> tuple[np.ndarray, float]:
    """Centroid (u, v) and principal-axis angle of a mask (binary, or soft: pixel weights)."""
    rows, cols = np.nonzero(mask)
    weights = np.asarray(mask, float)[rows, cols]
    u, v = cols.astype(float), rows.astype(float)
    total = weights.sum()
    cu, cv_ = (weights * u).sum() / total, (weights * v).sum() / total
    du, dv = u - cu, v - cv_
    mu20, mu02 = (weights * du * du).sum() / total, (weights * dv * dv).sum() / total
    mu11 = (weights * du * dv).sum() / total
    angle = 0.5 * np.arctan2(2.0 * mu11, mu20 - mu02)
    return np.array([cu, cv_]), angle


def _shifted(mask: np.ndarray, shift_uv: np.ndarray) -> np.ndarray:
    """``mask`` translated by a sub-pixel shift (u right, v down), as a soft float mask."""
    M = np.array([[1.0, 0.0, shift_uv[0]], [0.0, 1.0, shift_uv[1]]], np.float32)
    h, w = mask.shape
    return cv2.warpAffine(mask.astype(np.float32), M, (w, h), flags=cv2.INTER_LINEAR, borderValue=0.0)


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two masks (soft masks in [0, 1]: sum of min over sum of max)."""
    a, b = a.astype(np.float32), b.astype(np.float32)
    union = np.maximum(a, b).sum()
    return float(np.minimum(a, b).sum() / union) if union else 0.0


def wrap_yaw(yaw_rad: float, symmetry: int) -> float:
    """Yaw in [-period/2, period/2) for an object of n-fold symmetry (period 2*pi/n)."""
    if symmetry == 0:
        return 0.0
    period = 2.0 * np.pi / symmetry
    return float((yaw_rad + period / 2.0) % period - period / 2.0)


def yaw_error_rad(estimate: float, truth: float, symmetry: int) -> float:
    """Absolute yaw error modulo the object's symmetry (0 for rotationally symmetric objects)."""
    if symmetry == 0:
        return 0.0
    return abs(wrap_yaw(estimate - truth, symmetry))


def _pixel_jacobian(camera: CameraModel, point_world_m: np.ndarray, step_m: float = 1e-3) -> np.ndarray:
    """d(u, v)/d(x, y) of a world point's projection (2x2), by central differences."""
    J = np.zeros((2, 2))
    for k in range(2):
        delta = np.zeros(3)
        delta[k] = step_m
        J[:, k] = (camera.project(point_world_m + delta)[0] - camera.project(point_world_m - delta)[0]) / (2 * step_m)
    return J


def overlap_shift(rendered: np.ndarray, observed: np.ndarray, max_shift_px: int = OVERLAP_SHIFT_PX) -> np.ndarray:
    """The sub-pixel shift (u right, v down; within +-``max_shift_px``) that lays the ``rendered``
    mask (soft or binary) over the ``observed`` one with the largest overlap, both blurred by
    ``OVERLAP_BLUR_PX`` (so a mask a pixel wider than the other all round peaks at its centre).

    Unlike the difference of the centroids, a part of the observed mask the rendering lacks (a
    mug's handle, a strip of shadow the colour rule takes in) pulls the shift only where it joins
    the body: moving the rendering onto it loses more of the body's overlap than it gains."""
    both = (np.asarray(rendered, np.float32) > 0) | np.asarray(observed, bool)
    rows, cols = np.nonzero(both)
    pad, up = int(max_shift_px), OVERLAP_UPSAMPLE
    margin = pad + 2 * int(np.ceil(OVERLAP_BLUR_PX))  # room for the blur and the shifts around both masks
    r0, r1, c0, c1 = rows.min() - margin, rows.max() + 1 + margin, cols.min() - margin, cols.max() + 1 + margin

    def window(mask, extra):  # the masks' box grown by ``extra``, zeros beyond the image
        padded = cv2.copyMakeBorder(np.asarray(mask, np.float32), margin + pad, margin + pad, margin + pad,
                                    margin + pad, cv2.BORDER_CONSTANT, value=0.0)
        off = margin + pad
        cut = padded[r0 - extra + off:r1 + extra + off, c0 - extra + off:c1 + extra + off]
        blurred = cv2.GaussianBlur(cut, (0, 0), OVERLAP_BLUR_PX)
        return cv2.resize(blurred, None, fx=up, fy=up, interpolation=cv2.INTER_LINEAR)

    score = cv2.matchTemplate(window(observed, pad), window(rendered, 0), cv2.TM_CCORR)
    peak = np.array(np.unravel_index(int(np.argmax(score)), score.shape), float)  # (row, col)
    for axis in range(2):  # a parabola through the peak and its neighbours: the sub-sample maximum
        k = int(peak[axis])
        if 0 < k < score.shape[axis] - 1:
            at = [int(peak[0]), int(peak[1])]
            values = []
            for d in (-1, 0, 1):
                at[axis] = k + d
                values.append(float(score[tuple(at)]))
            curvature = values[0] - 2 * values[1] + values[2]
            if curvature < 0:
                peak[axis] += 0.5 * (values[0] - values[2]) / curvature
    shift_rc = peak / up - pad
    return np.array([shift_rc[1], shift_rc[0]])


def _refine_positions(poses, observed, objects, camera, table_z_m, render_masks, max_iterations, tolerance_px,
                      max_step_m, observed_masks=None) -> tuple[int, dict[str, float]]:
    """Gauss-Newton on the rendered-vs-observed centroid, or with ``observed_masks`` on the shift of
    largest overlap (``overlap_shift``); keeps each object's best iterate."""
    errors = {name: float("nan") for name in poses}
    best = {name: (np.inf, pose.copy()) for name, pose in poses.items()}
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        rendered = render_masks({n: tuple(p) for n, p in poses.items()})
        residuals = {}
        for obj in objects:
            mask = rendered.get(obj.name)
            if mask is None or not mask.any():
                continue  # rendered out of view or hidden: keep the back-projection
            if observed_masks is None:
                residuals[obj.name] = observed[obj.name] - _centroid_and_axis(mask)[0]
            else:
                residuals[obj.name] = overlap_shift(mask, observed_masks[obj.name])
            err = float(np.linalg.norm(residuals[obj.name]))
            if err < best[obj.name][0]:
                best[obj.name] = (err, poses[obj.name].copy())
        if not residuals or max(np.linalg.norm(r) for r in residuals.values()) < tolerance_px:
            break
        for obj in objects:
            if obj.name not in residuals:
                continue
            x, y, _ = poses[obj.name]
            point = np.array([x, y, table_z_m + obj.centroid_height_m])
            step = np.linalg.lstsq(_pixel_jacobian(camera, point), residuals[obj.name], rcond=None)[0]
            norm = np.linalg.norm(step)
            if norm > max_step_m:
                step *= max_step_m / norm
            poses[obj.name][:2] += step
    for name, (err, pose) in best.items():
        if np.isfinite(err):
            poses[name][:] = pose
            errors[name] = err
    return iterations, errors


def _luma(image_rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(image_rgb), cv2.COLOR_RGB2GRAY).astype(np.float32)


def _appearance_score(observed_luma: np.ndarray, rendered_luma: np.ndarray, window,
                      weight: np.ndarray | None = None) -> float:
    """Best normalised cross-correlation of the observed window within the rendered one (+-pad px);
    with ``weight`` (HxW, 0 or 1) only over the observed window's pixels it marks."""
    r0, r1, c0, c1 = window
    pad, up = APPEARANCE_PAD_PX, APPEARANCE_UPSAMPLE
    h, w = rendered_luma.shape
    search = rendered_luma[max(0, r0 - pad):min(h, r1 + pad), max(0, c0 - pad):min(w, c1 + pad)]
    template = observed_luma[r0:r1, c0:c1]
    search = cv2.resize(search, None, fx=up, fy=up, interpolation=cv2.INTER_LINEAR)
    template = cv2.resize(template, None, fx=up, fy=up, interpolation=cv2.INTER_LINEAR)
    if search.shape[0] < template.shape[0] or search.shape[1] < template.shape[1]:
        return -1.0
    if weight is None:
        return float(cv2.matchTemplate(search, template, cv2.TM_CCOEFF_NORMED).max())
    weight = cv2.resize(np.asarray(weight[r0:r1, c0:c1], np.float32), None, fx=up, fy=up,
                        interpolation=cv2.INTER_LINEAR)
    scores = cv2.matchTemplate(search, template, cv2.TM_CCOEFF_NORMED, mask=weight)
    scores[~np.isfinite(scores)] = -1.0  # a flat patch of the rendering correlates with nothing
    return float(scores.max())


def _search_yaw(obj: ObjectGeometry, poses, observed_mask, render_masks, grid: tuple[int, int],
                image_rgb: np.ndarray | None = None, render_image: RenderImage | None = None,
                appearance_window: str = "box") -> float:
    """Yaw (within one symmetry period) whose rendering best matches the frame; the luminance
    compared over the observed mask's box (``appearance_window`` ``box``) or only over the object's
    pixels in it (``object``: the observed mask grown by a pixel)."""
    period = 2.0 * np.pi / obj.yaw_symmetry
    n_coarse, n_fine = grid
    n_coarse = max(n_coarse, int(np.ceil(period / np.deg2rad(10.0))))  # coarse steps of at most 10 deg

    def trial(yaw: float) -> dict:
        poses_ = {n: tuple(p) for n, p in poses.items()}
        poses_[obj.name] = (poses[obj.name][0], poses[obj.name][1], yaw)
        return poses_

    if render_image is not None and image_rgb is not None:
        observed_luma = _luma(image_rgb)
        rows, cols = np.nonzero(observed_mask)
        h, w = observed_mask.shape
        window = (max(0, rows.min() - APPEARANCE_PAD_PX), min(h, rows.max() + 1 + APPEARANCE_PAD_PX),
                  max(0, cols.min() - APPEARANCE_PAD_PX), min(w, cols.max() + 1 + APPEARANCE_PAD_PX))

        weight = None
        if appearance_window == "object":  # the room round the object (its grain, shadows) does not count
            weight = cv2.dilate(observed_mask.astype(np.uint8), np.ones((3, 3), np.uint8))

        def score(yaw: float) -> float:
            return _appearance_score(observed_luma, _luma(render_image(trial(yaw))), window, weight)
    else:
        observed_centroid = _centroid_and_axis(observed_mask)[0]

        def score(yaw: float) -> float:
            mask = render_masks(trial(yaw)).get(obj.name)
            if mask is None or not mask.any():
                return 0.0
            # Compare shapes, not positions: the silhouette centroid moves with yaw for shapes
            # like a lying tapered cup, and the position is refined again afterwards.
            shift = observed_centroid - _centroid_and_axis(mask)[0]
            return mask_iou(_shifted(mask, shift), observed_mask)

    coarse = poses[obj.name][2] + np.arange(n_coarse) * period / n_coarse
    scores = [score(y) for y in coarse]
    best = float(coarse[int(np.argmax(scores))])
    step = period / n_coarse
    fine = best + np.linspace(-step, step, n_fine)
    fine_scores = [score(y) for y in fine]
    # Several yaws can tie on a pixel grid: take the middle of the best plateau.
    top = np.flatnonzero(np.isclose(fine_scores, max(fine_scores)))
    return wrap_yaw(float(np.mean(fine[top])), obj.yaw_symmetry)


def estimate_initial_poses(
    image_rgb: np.ndarray,
    segmenter: Segmenter,
    camera: CameraModel,
    table_z_m: float,
    objects: Sequence[ObjectGeometry],
    render_masks: RenderMasks | None = None,
    max_iterations: int = 8,
    tolerance_px: float = 0.25,
    max_step_m: float = 0.03,
    offsets: Mapping[str, Sequence[float]] | None = None,
    yaw_grid: tuple[int, int] = (16, 11),
    render_image: RenderImage | None = None,
    match: str = "centroid",
    appearance_window: str = "box",
) -> dict[str, PoseEstimate]:
    """Estimate each object's planar pose from `image_rgb`; see the module docstring. ``match``:
    how a rendered silhouette is laid over the observed one in the position refinement:
    ``centroid`` (their centroids coincide) or ``overlap`` (the shift of largest overlap,
    ``overlap_shift``: robust to parts of the object the model lacks). ``appearance_window``: the
    pixels the yaw search's luminance is compared over, the observed mask's box (``box``) or the
    object's own pixels in it (``object``: what lies round the object, a textured table, a shadow,
    a distractor, does not count)."""
    if match not in MATCHES:
        raise ValueError(f"match: one of {MATCHES}, got {match!r}")
    if appearance_window not in APPEARANCE_WINDOWS:
        raise ValueError(f"appearance_window: one of {APPEARANCE_WINDOWS}, got {appearance_window!r}")
    masks = segmenter.segment(image_rgb)
    observed, poses, areas = {}, {}, {}
    for obj in objects:
        mask = masks.get(obj.name)
        if mask is None or not mask.any():
            raise InitEstimationError(f"object {obj.name!r} is not visible in the frame")
        centroid, axis_angle = _centroid_and_axis(mask)
        plane_z = table_z_m + obj.centroid_height_m
        centre = camera.backproject_to_plane(centroid, plane_z)
        yaw = 0.0
        if obj.yaw_symmetry:
            tip_px = centroid + 5.0 * np.array([np.cos(axis_angle), np.sin(axis_angle)])
            tip = camera.backproject_to_plane(tip_px, plane_z)
            yaw = wrap_yaw(float(np.arctan2(tip[1] - centre[1], tip[0] - centre[0])), obj.yaw_symmetry)
        observed[obj.name] = centroid
        poses[obj.name] = np.array([centre[0], centre[1], yaw])
        areas[obj.name] = int(mask.sum())

    errors = {name: float("nan") for name in poses}
    iterations = 0
    if render_masks is not None:
        by_overlap = masks if match == "overlap" else None
        iterations, errors = _refine_positions(poses, observed, objects, camera, table_z_m, render_masks,
                                               max_iterations, tolerance_px, max_step_m, by_overlap)
        yawed = [obj for obj in objects if obj.yaw_symmetry]
        if yawed:
            for obj in yawed:
                poses[obj.name][2] = _search_yaw(obj, poses, masks[obj.name], render_masks, yaw_grid, image_rgb,
                                                 render_image, appearance_window)
            more, errors = _refine_positions(poses, observed, objects, camera, table_z_m, render_masks,
                                             max_iterations, tolerance_px, max_step_m, by_overlap)
            iterations += more

    offsets = offsets or {}
    estimates = {}
    for obj in objects:
        dx, dy, dyaw = (list(offsets.get(obj.name, ())) + [0.0, 0.0, 0.0])[:3]
        x, y, yaw = poses[obj.name]
        estimates[obj.name] = PoseEstimate(
            name=obj.name,
            x_m=float(x + dx),
            y_m=float(y + dy),
            yaw_rad=wrap_yaw(float(yaw + dyaw), obj.yaw_symmetry) if obj.yaw_symmetry else float(yaw + dyaw),
            reproj_error_px=errors[obj.name],
            iterations=iterations,
            mask_area_px=areas[obj.name],
        )
    return estimates
