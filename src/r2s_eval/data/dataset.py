"""Thin layer over LeRobotDataset v3: the feature layout we record, and per-episode reads.

Data files hold many episodes each; an episode is found through `meta/episodes` (its
`dataset_from_index`/`dataset_to_index` rows and per-camera video timestamps).
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from r2s_eval.errors import ConfigError, DataError
from r2s_eval.utils.io import current_provenance, write_json
from r2s_eval.utils.numerics import job_threads

STATE_KEY = "observation.state"
ACTION_KEY = "action"
IMAGE_PREFIX = "observation.images."
PROVENANCE_FILE = "meta/r2s_eval_provenance.json"  # config hash and version of the stage that recorded it

log = logging.getLogger(__name__)


def camera_key(camera: str) -> str:
    return f"{IMAGE_PREFIX}{camera}"


def lerobot_features(
    state_names: Sequence[str],
    action_names: Sequence[str],
    cameras: Sequence[str],
    image_hw: tuple[int, int] | Mapping[str, tuple[int, int]],
) -> dict:
    """Feature spec of our robot datasets: joint state, joint-target action, one video per camera
    (``image_hw``: every camera's (height, width), or each camera's own)."""
    features = {
        STATE_KEY: {"dtype": "float32", "shape": (len(state_names),), "names": list(state_names)},
        ACTION_KEY: {"dtype": "float32", "shape": (len(action_names),), "names": list(action_names)},
    }
    for cam in cameras:
        height, width = image_hw[cam] if isinstance(image_hw, Mapping) else image_hw
        features[camera_key(cam)] = {
            "dtype": "video",
            "shape": (height, width, 3),
            "names": ["height", "width", "channels"],
        }
    return features


class DatasetRecorder:
    """Record episodes into a new LeRobotDataset that appears at `root` only when complete.

    Frames go to a temporary sibling directory; `close()` finalises and renames it, so a
    killed recording never leaves a dataset that looks whole.
    """

    def __init__(self, root: str | Path, repo_id: str, fps: int, features: dict, robot_type: str,
                 video: dict | None = None):
        """``video``: LeRobot's camera-video encoder settings (``RGBEncoderConfig`` fields such as
        vcodec, preset, crf); None: LeRobot's defaults (AV1)."""
        from lerobot.configs.video import RGBEncoderConfig
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        from r2s_eval.data.image_stats import use_counted_image_stats

        use_counted_image_stats()  # the video encoder's per-frame statistics, at about a fifth of the CPU
        self.root = Path(root)
        self.tmp_root = self.root.with_name(f".{self.root.name}.recording")
        if self.tmp_root.exists():
            shutil.rmtree(self.tmp_root)
        self.root.parent.mkdir(parents=True, exist_ok=True)
        try:
            rgb_encoder = RGBEncoderConfig(**video) if video else None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{self.root}: video encoder settings {video} are not LeRobot's: {exc}") from exc
        self._dataset = LeRobotDataset.create(
            repo_id,
            fps=fps,
            features=features,
            root=self.tmp_root,
            robot_type=robot_type,
            use_videos=True,
            video_backend="pyav",
            streaming_encoding=True,  # encode while recording: no PNG round trip
            # LeRobot's streaming encoder drops a frame when its queue stays full for 0.1 s (right
            # for a live camera); a recording here is offline and must wait instead. Unbounded:
            # save_episode drains the queue, so it never holds more than one episode.
            encoder_queue_maxsize=0,
            # One thread per camera's encoder (the cameras encode side by side): x264's output
            # depends on its thread count, and a recording must be the same bytes whatever
            # threads its job was given (a cluster node and a laptop give different ones).
            encoder_threads=1,
            rgb_encoder=rgb_encoder,
        )
        self._image_keys = [k for k, f in features.items() if f["dtype"] == "video"]
        self.fps = int(fps)
        self.num_episodes = 0
        # submit_episode's own thread, when the job has a second one to give it.
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="recorder") if job_threads() > 1 else None
        self._pending: Future | None = None

    def add_episode(self, frames: Iterable[tuple[dict, np.ndarray]], task: str) -> int:
        """Append one episode of (observation, action) pairs; returns its episode index."""
        n = 0
        for obs, action in frames:
            frame = {
                STATE_KEY: np.asarray(obs[STATE_KEY], dtype=np.float32),
                ACTION_KEY: np.asarray(action, dtype=np.float32),
                "task": task,
            }
            for key in self._image_keys:
                frame[key] = obs[key]
            self._dataset.add_frame(frame)
            n += 1
        if n == 0:
            raise DataError(f"episode {self.num_episodes} of {self.root} has no frames")
        self._dataset.save_episode()
        self._check_videos(n)
        self.num_episodes += 1
        return self.num_episodes - 1

    def submit_episode(self, frames: Sequence[tuple[dict, np.ndarray]], task: str) -> int:
        """`add_episode`, on the recorder's own thread when the job has two or more, so the caller
        makes its next episode while this one is encoded; returns the episode's index. One episode
        waits at most: the next call first finishes it (and raises its error)."""
        self.wait()
        if self._worker is None:
            return self.add_episode(frames, task)
        self._pending = self._worker.submit(self.add_episode, frames, task)
        return self.num_episodes

    def wait(self) -> None:
        """Finish the episode handed to `submit_episode` (raising its error)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def _check_videos(self, frames: int) -> None:
        """Every camera's video of the episode just saved holds all its frames: a frame lost by the
        encoder would shift the video against the episode's rows, silently."""
        episode = self._dataset.meta.latest_episode
        for key in self._image_keys:
            span = episode[f"videos/{key}/to_timestamp"][0] - episode[f"videos/{key}/from_timestamp"][0]
            if abs(span * self.fps - frames) > 0.5:
                raise DataError(
                    f"{self.root}: episode {self.num_episodes}, camera {key}: the video encoder wrote "
                    f"{span * self.fps:.0f} frames of {frames}"
                )

    def close(self) -> None:
        self.wait()
        self._shutdown()
        self._dataset.finalize()
        if self.num_episodes == 0:
            raise DataError(f"no episode was recorded into {self.root}")
        # LeRobot's own meta files stay as LeRobot writes them; what made the dataset sits beside them.
        provenance = current_provenance()
        if provenance:
            write_json(self.tmp_root / PROVENANCE_FILE, provenance)
        if self.root.exists():
            shutil.rmtree(self.root)
        self.tmp_root.rename(self.root)
        # Unused PNG staging folders would make the artefact depend on recording details.
        images = self.root / "images"
        if images.exists():
            shutil.rmtree(images)

    def abort(self) -> None:
        try:
            self.wait()
        except Exception:  # the episode being encoded is discarded with the rest
            pass
        self._shutdown()
        try:  # stop an unfinished episode's encoder threads before their folder goes
            self._dataset.clear_episode_buffer()
        except Exception:
            pass
        shutil.rmtree(self.tmp_root, ignore_errors=True)

    def _shutdown(self) -> None:
        if self._worker is not None:
            self._worker.shutdown()
            self._worker = None

    def __enter__(self) -> DatasetRecorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def open_metadata(root: str | Path, repo_id: str = "local/dataset"):
    """Load a local dataset's metadata with lerobot; never reaches for the hub.

    lerobot falls back to downloading from the hub when a metadata file is missing; the strict
    local read first turns that case (and unreadable files) into an error naming the file.
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    from r2s_eval.data.contract import read_metadata

    read_metadata(root)
    return LeRobotDatasetMetadata(repo_id, root=Path(root))


def episode_frames(root: str | Path, meta, episode_index: int) -> pd.DataFrame:
    """The per-frame rows (state, action, timestamps) of one episode."""
    row = meta.episodes[int(episode_index)]
    path = Path(root) / meta.data_path.format(
        chunk_index=row["data/chunk_index"], file_index=row["data/file_index"]
    )
    data = pd.read_parquet(path)
    return data[data["episode_index"] == episode_index].sort_values("frame_index").reset_index(drop=True)
