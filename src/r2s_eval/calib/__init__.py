"""Real-to-sim calibration: initial object poses from a first camera frame, per-task offsets,
and the robot's joint offsets.

``scene`` (the calibrated sim as the estimator sees it: object geometry, camera model, mask and
image renderers), ``episodes`` (estimates for a dataset's episodes) and ``joints`` (joint offsets
from the recordings' replay residuals) build on ``r2s_eval.sim`` and are imported from their
modules, so this package itself loads no simulator.
"""

from r2s_eval.calib.estimate import (
    CameraModel,
    InitEstimationError,
    ObjectGeometry,
    PoseEstimate,
    estimate_initial_poses,
    yaw_error_rad,
)
from r2s_eval.calib.offsets import calibration_subset, fit_offsets, median_error_mm, read_measured_poses
from r2s_eval.calib.scoring import score_estimates, scored_errors
from r2s_eval.calib.segment import HSVSegmenter, Segmenter, make_segmenter

__all__ = [
    "CameraModel",
    "HSVSegmenter",
    "InitEstimationError",
    "ObjectGeometry",
    "PoseEstimate",
    "Segmenter",
    "calibration_subset",
    "estimate_initial_poses",
    "fit_offsets",
    "median_error_mm",
    "read_measured_poses",
    "score_estimates",
    "scored_errors",
    "make_segmenter",
    "yaw_error_rad",
]
