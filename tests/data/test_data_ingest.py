"""Ingest: a good dataset is indexed; every kind of bad input fails naming the episode."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from r2s_eval.errors import DataError
from r2s_eval.data import (DatasetRecorder, DatasetValidationError, IngestSpec, episode_frames, ingest_dataset,
                           lerobot_features, open_metadata)

INSTRUCTION = "Pick the Cup and Place it on the Plate"
NAMES = [f"j{i}" for i in range(14)]


def make_dataset(root: Path, episodes: int = 3, length: int = 12) -> Path:
    features = lerobot_features(NAMES, NAMES, ["head_left"], (32, 32))
    rng = np.random.default_rng(0)
    with DatasetRecorder(root, "local/test", 10, features, "test_robot") as rec:
        for _ in range(episodes):
            frames = []
            for t in range(length):
                image = np.full((32, 32, 3), 40, np.uint8)
                image[8:16, 4 + t : 12 + t] = (200, 30, 30)
                obs = {"observation.state": rng.normal(size=14), "observation.images.head_left": image}
                frames.append((obs, rng.normal(size=14)))
            rec.add_episode(frames, INSTRUCTION)
    return root


def spec(**changes) -> IngestSpec:
    base = dict(cameras=["head_left"], feature_names=NAMES, fps=10, tasks={INSTRUCTION: "cup_on_plate"},
                first_frame_camera="head_left", min_length=5)
    base.update(changes)
    return IngestSpec(**base)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("ds") / "teleop")


@pytest.fixture
def dataset_copy(dataset, tmp_path) -> Path:
    import shutil

    return Path(shutil.copytree(dataset, tmp_path / "teleop"))


def test_good_dataset_is_indexed(dataset, tmp_path):
    index, report = ingest_dataset(dataset, "local/test", spec(), tmp_path / "frames")
    assert list(index["episode_index"]) == [0, 1, 2]
    assert set(index["task"]) == {"cup_on_plate"} and (index["length"] == 12).all()
    assert report["episodes_usable"] == 3 and report["frames_usable"] == 36
    first = tmp_path / "frames" / index["first_frame"][0]
    assert first.stat().st_size > 0


def test_recorder_leaves_nothing_when_aborted(tmp_path):
    features = lerobot_features(NAMES, NAMES, ["head_left"], (32, 32))
    with pytest.raises(RuntimeError):
        with DatasetRecorder(tmp_path / "ds", "local/test", 10, features, "test_robot"):
            raise RuntimeError("operator interrupted")
    assert not (tmp_path / "ds").exists() and not any(tmp_path.iterdir())


def test_not_a_dataset(tmp_path):
    with pytest.raises(DatasetValidationError, match="no meta/info.json"):
        ingest_dataset(tmp_path, "local/test", spec(), tmp_path / "frames")


def test_nan_action_names_episode(dataset_copy, tmp_path):
    path = next((dataset_copy / "data").rglob("*.parquet"))
    data = pd.read_parquet(path)
    row = data.index[(data["episode_index"] == 1) & (data["frame_index"] == 4)][0]
    action = np.array(data.at[row, "action"], dtype=np.float32)
    action[3] = np.nan
    data.at[row, "action"] = action
    data.to_parquet(path)
    with pytest.raises(DatasetValidationError, match=r"episode 1: action has NaN/inf in 1 frame\(s\), first at frame 4"):
        ingest_dataset(dataset_copy, "local/test", spec(), tmp_path / "frames")


def test_drop_bad_episodes_keeps_the_rest(dataset_copy, tmp_path):
    path = next((dataset_copy / "data").rglob("*.parquet"))
    data = pd.read_parquet(path)
    rows = data.index[data["episode_index"] == 2]
    data.loc[rows, "observation.state"] = pd.Series([np.full(14, np.inf, np.float32)] * len(rows), index=rows)
    data.to_parquet(path)
    index, report = ingest_dataset(dataset_copy, "local/test", spec(drop_bad_episodes=True), tmp_path / "frames")
    assert list(index["episode_index"]) == [0, 1]
    assert "observation.state has NaN/inf" in report["dropped"]["2"][0]


def test_wrong_fps_and_missing_camera(dataset, tmp_path):
    with pytest.raises(DatasetValidationError, match="fps is 10, the world's robot.control_hz is 30"):
        ingest_dataset(dataset, "local/test", spec(fps=30), tmp_path / "frames")
    with pytest.raises(DatasetValidationError, match="camera feature 'observation.images.wrist_left' is missing"):
        ingest_dataset(dataset, "local/test", spec(cameras=["head_left", "wrist_left"]), tmp_path / "frames")
    # The world's robot maps other names: both sides' strays are named.
    other = [*NAMES[:6], "gripper_left"]
    with pytest.raises(DatasetValidationError, match=r"feature 'action' names \[.*not in robot.features: "
                                                     r"\['j6', .*'j13'\]; robot.features has, the dataset lacks: \['gripper_left'\]"):
        ingest_dataset(dataset, "local/test", spec(feature_names=other), tmp_path / "frames")
    with pytest.raises(DatasetValidationError, match=r"feature 'observation.state' names .* \(another order\)"):
        ingest_dataset(dataset, "local/test", spec(feature_names=NAMES[::-1]), tmp_path / "frames")


def test_a_state_outside_its_joint_ranges_is_a_wrong_unit(dataset, tmp_path):
    # The state is N(0, 1): inside a joint range of +-3 (as radians), outside one of +-0.05 (the
    # same joint's range read as if the dataset were in 60x larger units) nearly everywhere.
    wide = {name: (-3.0, 3.0) for name in NAMES}
    index, _ = ingest_dataset(dataset, "local/test", spec(feature_ranges=wide), tmp_path / "f")
    assert len(index) == 3
    narrow = {**wide, "j3": (-0.05, 0.05)}
    with pytest.raises(DatasetValidationError) as error:
        ingest_dataset(dataset, "local/test", spec(feature_ranges=narrow), tmp_path / "f2")
    message = str(error.value)
    assert "observation.state 'j3' lies inside its joint's range [-0.05, 0.05]" in message, message
    assert "robot.features[3]" in message and "wrong unit" in message and "'j2'" not in message


def test_unknown_task_and_short_episodes(dataset, tmp_path):
    with pytest.raises(DatasetValidationError, match="episode 0: task 'Pick the Cup and Place it on the Plate' is not one of"):
        ingest_dataset(dataset, "local/test", spec(tasks={"Stack the Two Blocks": "stack_blocks"}), tmp_path / "f")
    with pytest.raises(DatasetValidationError, match=r"episode 2: length 12 outside \[20, 10000\]"):
        ingest_dataset(dataset, "local/test", spec(min_length=20), tmp_path / "f")


def test_corrupt_video_names_camera_and_episode(dataset_copy, tmp_path):
    video = next((dataset_copy / "videos").rglob("*.mp4"))
    blob = video.read_bytes()
    video.write_bytes(blob[: len(blob) // 3])
    with pytest.raises(DatasetValidationError, match=r"episode \d+: camera head_left: only \d+ of 12 frames decode"):
        ingest_dataset(dataset_copy, "local/test", spec(), tmp_path / "frames")


def _frames(length: int) -> list[tuple[dict, np.ndarray]]:
    image = np.full((32, 32, 3), 40, np.uint8)
    return [({"observation.state": np.zeros(14), "observation.images.head_left": image}, np.zeros(14))
            for _ in range(length)]


def test_recorder_waits_for_a_slow_encoder(tmp_path, monkeypatch):
    """LeRobot's streaming encoder drops frames when its queue stays full (live capture); an
    offline recording must wait for it instead, so every frame reaches the video."""
    from lerobot.datasets import video_utils

    run = video_utils._CameraEncoderThread.run

    def slow_start(self):
        time.sleep(0.5)  # the first frames pile up in the queue meanwhile
        run(self)

    monkeypatch.setattr(video_utils._CameraEncoderThread, "run", slow_start)
    features = lerobot_features(NAMES, NAMES, ["head_left"], (32, 32))
    with DatasetRecorder(tmp_path / "ds", "local/test", 10, features, "test_robot") as rec:
        rec.add_episode(_frames(60), INSTRUCTION)  # twice the encoder's default queue
    index, _ = ingest_dataset(tmp_path / "ds", "local/test", spec(), tmp_path / "frames")
    assert index["length"].tolist() == [60]


def test_recorder_refuses_a_video_missing_frames(tmp_path, monkeypatch):
    """A frame lost by the encoder would shift the video against the episode's rows: the recording
    stops naming the episode and camera, and no dataset appears."""
    from lerobot.datasets import video_utils

    feed = video_utils.StreamingVideoEncoder.feed_frame
    fed = {"n": 0}

    def drop_third(self, video_key, image):
        fed["n"] += 1
        if fed["n"] != 3:
            feed(self, video_key, image)

    monkeypatch.setattr(video_utils.StreamingVideoEncoder, "feed_frame", drop_third)
    features = lerobot_features(NAMES, NAMES, ["head_left"], (32, 32))
    with pytest.raises(DataError, match=r"episode 0, camera observation.images.head_left: .* wrote 9 frames of 10"):
        with DatasetRecorder(tmp_path / "ds", "local/test", 10, features, "test_robot") as rec:
            rec.add_episode(_frames(10), INSTRUCTION)
    assert not (tmp_path / "ds").exists()


def _moving_frames(length: int, seed: int, size: int = 32) -> list[tuple[dict, np.ndarray]]:
    rng = np.random.default_rng(seed)
    texture = rng.integers(0, 60, (size, size, 3), dtype=np.uint8)  # something for the encoder to work at
    frames = []
    for t in range(length):
        image = texture + 40
        image[8:16, t : 8 + t] = (200, 30, 30)
        frames.append(({"observation.state": rng.normal(size=14), "observation.images.head_left": image}, rng.normal(size=14)))
    return frames


def _record(root: Path, threads: str, monkeypatch, submit: bool, video: dict | None = None, size: int = 32) -> list[int]:
    monkeypatch.setenv("OMP_NUM_THREADS", threads)
    features = lerobot_features(NAMES, NAMES, ["head_left"], (size, size))
    with DatasetRecorder(root, "local/test", 10, features, "test_robot", video=video) as rec:
        add = rec.submit_episode if submit else rec.add_episode
        return [add(_moving_frames(8 + e, e, size), INSTRUCTION) for e in range(3)]


def test_episodes_encoded_beside_the_next_make_the_same_dataset(tmp_path, monkeypatch):
    """With two job threads an episode is encoded on the recorder's thread while the caller makes
    the next one; the dataset is the one add_episode records on one thread, indices and video
    bytes included (a Slurm job and a local one get different thread counts)."""
    video = {"vcodec": "h264", "preset": "ultrafast", "crf": 18}
    assert _record(tmp_path / "inline", "1", monkeypatch, submit=False, video=video, size=128) == [0, 1, 2]
    assert _record(tmp_path / "beside", "4", monkeypatch, submit=True, video=video, size=128) == [0, 1, 2]
    videos = {name: sorted((tmp_path / name / "videos").rglob("*.mp4")) for name in ("inline", "beside")}
    assert len(videos["inline"]) == len(videos["beside"]) >= 1
    assert [v.read_bytes() for v in videos["inline"]] == [v.read_bytes() for v in videos["beside"]]
    inline, beside = (open_metadata(tmp_path / name, "local/test") for name in ("inline", "beside"))
    for e in range(3):
        pd.testing.assert_frame_equal(episode_frames(tmp_path / "inline", inline, e),
                                      episode_frames(tmp_path / "beside", beside, e))
    index, _ = ingest_dataset(tmp_path / "beside", "local/test", spec(min_length=5), tmp_path / "frames")
    assert index["length"].tolist() == [8, 9, 10]


def test_an_episode_that_fails_on_the_recorder_thread_stops_the_recording(tmp_path, monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    features = lerobot_features(NAMES, NAMES, ["head_left"], (32, 32))
    bad = _moving_frames(8, 0)
    bad[3][0]["observation.images.head_left"] = np.zeros((16, 16, 3), np.uint8)  # wrong camera size
    with pytest.raises(Exception, match="head_left"):
        with DatasetRecorder(tmp_path / "ds", "local/test", 10, features, "test_robot") as rec:
            rec.submit_episode(bad, INSTRUCTION)
            rec.submit_episode(_moving_frames(8, 1), INSTRUCTION)  # raises the first episode's error
    assert not (tmp_path / "ds").exists() and not any(tmp_path.iterdir())


def test_recorder_encodes_with_the_configured_codec(tmp_path, monkeypatch):
    import av

    _record(tmp_path / "ds", "1", monkeypatch, submit=False, video={"vcodec": "h264", "preset": "ultrafast", "crf": 18})
    info = open_metadata(tmp_path / "ds", "local/test").features["observation.images.head_left"]["info"]
    assert info["video.codec"] == "h264"
    video = next((tmp_path / "ds" / "videos").rglob("*.mp4"))
    with av.open(str(video)) as f:
        assert f.streams.video[0].codec_context.name == "h264"
        assert sum(1 for _ in f.decode(video=0)) == 8 + 9 + 10


def test_recorder_refuses_a_codec_lerobot_does_not_know(tmp_path):
    from r2s_eval.errors import ConfigError

    features = lerobot_features(NAMES, NAMES, ["head_left"], (32, 32))
    with pytest.raises(ConfigError, match=r"ds: video encoder settings \{'vcodec': 'divx'\} are not LeRobot's: .*divx"):
        DatasetRecorder(tmp_path / "ds", "local/test", 10, features, "test_robot", video={"vcodec": "divx"})
    assert not (tmp_path / "ds").exists()
