"""Real-to-sim calibration: initial object poses from a first camera frame."""

from r2s_eval.calib.estimate import (
    CameraModel,
    InitEstimationError,
    ObjectGeometry,
    PoseEstimate,
    estimate_initial_poses,
    yaw_error_rad,
)
from r2s_eval.calib.segment import HSVSegmenter, Segmenter, make_segmenter

__all__ = [
    "CameraModel",
    "HSVSegmenter",
    "InitEstimationError",
    "ObjectGeometry",
    "PoseEstimate",
    "Segmenter",
    "estimate_initial_poses",
    "make_segmenter",
    "yaw_error_rad",
]
