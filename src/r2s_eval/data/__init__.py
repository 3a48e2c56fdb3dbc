"""Robot datasets: LeRobotDataset v3 recording, reading and validation (ingest)."""

from r2s_eval.data.dataset import (
    ACTION_KEY,
    IMAGE_PREFIX,
    STATE_KEY,
    DatasetRecorder,
    camera_key,
    episode_frames,
    lerobot_features,
    open_metadata,
)
from r2s_eval.data.ingest import DatasetValidationError, IngestSpec, ingest_dataset

__all__ = [
    "ACTION_KEY",
    "IMAGE_PREFIX",
    "STATE_KEY",
    "DatasetRecorder",
    "DatasetValidationError",
    "IngestSpec",
    "camera_key",
    "episode_frames",
    "ingest_dataset",
    "lerobot_features",
    "open_metadata",
]
