"""The calibrated sim as the pose estimator sees it: object geometry, camera model, renders.

Everything here comes from the nominal (calibrated) world: its camera is the calibration and
its renders are what the refinement matches. Nothing reads the twin's parameters or truth.

The renders are pinhole images; a recorded frame is compared with them as the calibrated sim's
pinhole camera would see it (``pinhole_frame``: undistorted through the lens the calibration fitted
for that camera, ``WorldParams.lens_distortion``), so both sides are undistorted.
"""

from __future__ import annotations

import numpy as np

from r2s_eval.calib.estimate import CameraModel, ObjectGeometry
from r2s_eval.sim import TabletopEnv
from r2s_eval.sim.sensor import undistorted, undistorted_coverage


def object_geometries(env: TabletopEnv) -> list[ObjectGeometry]:
    """Approximate silhouette-centre heights; the render-based refinement removes the rest."""
    geoms = []
    for name in env.task.object_names:
        height = env.task.object(name).kind_object.placed_height_m(env.object_dims(name), env.task.placement(name))
        base = 0.0
        parent = env.task.init_regions[name].relative_to
        if parent is not None:  # resting inside another object (a block in a box)
            base = env.task.object(parent).kind_object.support_top_m(env.object_dims(parent))
        geoms.append(ObjectGeometry(name, centroid_height_m=base + 0.5 * height, yaw_symmetry=env.task.yaw_symmetry(name)))
    return geoms


def camera_lens(env: TabletopEnv, camera: str):
    """The calibrated lens of ``camera`` (five coefficients), or None for a pinhole."""
    return env.params.lens_distortion.get(camera)


def pinhole_frame(env: TabletopEnv, camera: str, image: np.ndarray) -> np.ndarray:
    """``image`` (a frame ``camera`` recorded, RGB) as the calibrated sim's pinhole camera sees it:
    undistorted through that camera's calibrated lens (``env.params.lens_distortion``) with the
    camera's model K at the frame's size (``r2s_eval.sim.sensor.undistorted``). Without a lens
    (none fitted, or all zero) the frame itself, the same bytes."""
    lens = camera_lens(env, camera)
    return undistorted(image, env.camera_K(camera, image.shape[:2]), lens)


def pinhole_coverage(env: TabletopEnv, camera: str, size_hw: tuple[int, int]) -> np.ndarray:
    """bool[H, W]: the pixels of ``pinhole_frame``'s image the recorded frame covers (all of
    them without a lens)."""
    return undistorted_coverage(env.camera_K(camera, size_hw), camera_lens(env, camera), size_hw)


def camera_model(env: TabletopEnv, camera: str) -> CameraModel:
    return CameraModel(K=env.camera_K(camera), T_world_from_cam=env.camera_T_world_from_cam(camera))


def mask_renderer(env, camera: str, supersample: int = 1):
    """Render the sim's object masks for planar poses, from the calibrated camera.

    With ``supersample`` k > 1 the masks are rendered at k times the resolution and
    area-averaged back: soft masks (pixel coverage) whose centroid and overlap change
    smoothly with the pose, instead of in whole-pixel steps.
    """
    names = env.task.object_names
    h, w = env.image_size
    k = int(supersample)

    def render(poses):
        env.reset(poses, settle=False, observe=False)  # kinematics only: a pose hypothesis
        labels, label_names = env.render(camera, size=(h * k, w * k), segmentation=True)
        by_name = {n: label for label, n in label_names.items()}
        if k == 1:
            return {n: labels == by_name[n] for n in names}
        return {n: (labels == by_name[n]).reshape(h, k, w, k).mean(axis=(1, 3)) for n in names}

    return render


def image_renderer(env, camera: str):
    """Render the sim's clean RGB frame for planar poses, from the calibrated camera."""

    def render(poses):
        env.reset(poses, settle=False, observe=False)
        return env.render(camera)

    return render
