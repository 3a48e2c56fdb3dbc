"""Real-to-sim calibration: initial object poses from a first camera frame, per-task offsets."""

from r2s_eval.calib.estimate import (
    CameraModel,
    InitEstimationError,
    ObjectGeometry,
    PoseEstimate,
    estimate_initial_poses,
    yaw_error_rad,
)
from r2s_eval.calib.offsets import calibration_subset, fit_offsets
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
    "make_segmenter",
    "yaw_error_rad",
]
