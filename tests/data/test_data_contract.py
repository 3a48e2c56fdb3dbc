"""Damaged copies of a small valid dataset: ingest names the file, episode and camera of every fault,
never reaches for the network, and with `drop_bad_episodes` keeps the sound episodes.

The dataset is recorded in the test (two cameras, two tasks, four episodes over two data files);
each case damages a copy the way a broken recorder, a bad conversion or a hand edit would.
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.helpers.worlds import bundled_world
from r2s_eval.data import DatasetRecorder, DatasetValidationError, IngestSpec, ingest_dataset, lerobot_features

TASKS = ["Pick the Cup and Place it on the Plate", "Stack the Two Blocks"]
NAMES = [f"j{i}" for i in range(14)]
CAMERAS = ["head_left", "wrist_left"]
FPS, LENGTH, EPISODES = 10, 12, 4
EPISODES_FILE = "meta/episodes/chunk-000/file-000.parquet"
DATA_0 = "data/chunk-000/file-000.parquet"
DATA_1 = "data/chunk-000/file-001.parquet"
WRIST_VIDEO = "videos/observation.images.wrist_left/chunk-000/file-000.mp4"


def _record(root: Path) -> Path:
    features = lerobot_features(NAMES, NAMES, CAMERAS, (32, 32))
    rng = np.random.default_rng(0)
    with DatasetRecorder(root, "local/test", FPS, features, "test_robot") as rec:
        for e in range(EPISODES):
            frames = []
            for t in range(LENGTH):
                obs = {"observation.state": rng.normal(size=14)}
                for c, cam in enumerate(CAMERAS):
                    image = np.full((32, 32, 3), 40 + 60 * c, np.uint8)
                    image[8:16, 4 + t: 12 + t] = (200, 30, 30)
                    obs[f"observation.images.{cam}"] = image
                frames.append((obs, rng.normal(size=14)))
            rec.add_episode(frames, TASKS[e % 2])
    _split_last_episode(root)
    return root


def _split_last_episode(root: Path) -> None:
    """Move the last episode's rows into a second data file, as a larger recording would have them."""
    data = pd.read_parquet(root / DATA_0)
    last = EPISODES - 1
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(root / DATA_0)
    mask = pa.array(data["episode_index"] == last)
    pq.write_table(table.filter(mask), root / DATA_1)
    pq.write_table(table.filter(pa.compute.invert(mask)), root / DATA_0)
    episodes = pd.read_parquet(root / EPISODES_FILE)
    episodes.loc[episodes["episode_index"] == last, "data/file_index"] = 1
    episodes.to_parquet(root / EPISODES_FILE)


def spec(**changes) -> IngestSpec:
    base = dict(cameras=CAMERAS, feature_names=NAMES, fps=FPS,
                tasks={TASKS[0]: "cup_on_plate", TASKS[1]: "stack_blocks"}, first_frame_camera="head_left",
                min_length=5)
    base.update(changes)
    return IngestSpec(**base)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return _record(tmp_path_factory.mktemp("contract") / "teleop")


@pytest.fixture
def no_network(monkeypatch) -> list:
    """Record (and refuse) every attempt to open a network connection."""
    attempts: list = []

    def refuse(self, address, *args, **kwargs):
        if self.family in (socket.AF_INET, socket.AF_INET6):
            attempts.append(address)
            raise OSError(f"test: network connection to {address} refused")
        return real_connect(self, address, *args, **kwargs)

    real_connect = socket.socket.connect
    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket.socket, "connect_ex", lambda self, address: refuse(self, address) or 0)
    monkeypatch.setattr(socket, "getaddrinfo", lambda *a, **k: attempts.append(a) or (_ for _ in ()).throw(
        OSError("test: name resolution refused")))
    return attempts


# ----------------------------------------------------------------------------- damage
def _edit_parquet(root: Path, rel: str, edit: Callable[[pd.DataFrame], pd.DataFrame]) -> None:
    path = root / rel
    edit(pd.read_parquet(path)).to_parquet(path)


def _edit_info(root: Path, edit: Callable[[dict], None]) -> None:
    path = root / "meta/info.json"
    info = json.loads(path.read_text())
    edit(info)
    path.write_text(json.dumps(info))


def _duplicate_episode_row(root):
    _edit_parquet(root, EPISODES_FILE, lambda df: pd.concat([df, df[df["episode_index"] == 1]], ignore_index=True))


def _set_for_episode(rel: str, episode: int, column: str, value) -> Callable[[Path], None]:
    """A corruption: the rows of `episode` in the parquet file `rel` get `value` in `column`."""
    def edit(df):
        df.loc[df["episode_index"] == episode, column] = value
        return df

    return lambda root: _edit_parquet(root, rel, edit)


_renumber_episode = _set_for_episode(EPISODES_FILE, 2, "episode_index", 7)


def _wrist_camera_resolution(root):
    """Re-encode the second camera (not the one calibration reads) at another size."""
    import av

    path = root / WRIST_VIDEO
    with av.open(str(path)) as src:
        frames = [f.to_ndarray(format="rgb24") for f in src.decode(video=0)]
    with av.open(str(path), "w") as dst:
        stream = dst.add_stream("mpeg4", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = 24, 24, "yuv420p"
        for image in frames:
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image[:24, :24]), format="rgb24")
            for packet in stream.encode(frame):
                dst.mux(packet)
        for packet in stream.encode():
            dst.mux(packet)


def _shift_video_window(root):
    def edit(df):
        sel = df["episode_index"] == 2
        for col in ("from_timestamp", "to_timestamp"):
            df.loc[sel, f"videos/observation.images.wrist_left/{col}"] += 0.3
        return df

    _edit_parquet(root, EPISODES_FILE, edit)


def _offset_data_timestamps(root):
    def edit(df):
        df.loc[df["episode_index"] == 1, "timestamp"] += np.float32(0.5)
        return df

    _edit_parquet(root, DATA_0, edit)


def _narrow_state(root):
    def edit(df):
        rows = df.index[df["episode_index"] == 1]
        df["observation.state"] = [np.asarray(v, np.float32) for v in df["observation.state"]]
        for r in rows:
            df.at[r, "observation.state"] = np.asarray(df.at[r, "observation.state"][:13], np.float32)
        return df

    _edit_parquet(root, DATA_0, edit)


def _action_as_float64(root):
    def edit(df):
        df["action"] = [np.asarray(v, np.float64) for v in df["action"]]
        return df

    _edit_parquet(root, DATA_1, edit)


def _task_not_in_tasks_table(root):
    def edit(df):
        df["tasks"] = [["Put the Ball in the Box"] if e == 3 else list(t) for e, t in zip(df["episode_index"], df["tasks"])]
        return df

    _edit_parquet(root, EPISODES_FILE, edit)


_rows_carry_other_task = _set_for_episode(DATA_0, 2, "task_index", 1)


def _wrong_totals(root):
    def edit(info):
        info["total_episodes"] = 5
        info["total_frames"] = 50

    _edit_info(root, edit)


def _info_not_json(root):
    (root / "meta/info.json").write_text('{"codebase_version": "v3.0", "fps": 10,')


def _stats_not_json(root):
    (root / "meta/stats.json").write_text("not json at all")


def _truncated_data_file(root):
    blob = (root / DATA_0).read_bytes()
    (root / DATA_0).write_bytes(blob[: len(blob) // 2])


def _truncated_episodes_file(root):
    blob = (root / EPISODES_FILE).read_bytes()
    (root / EPISODES_FILE).write_bytes(blob[: len(blob) // 2])


def _version_2_1(root):
    _edit_info(root, lambda info: info.update(codebase_version="v2.1"))


def _no_tasks_file(root):
    (root / "meta/tasks.parquet").unlink()


def _no_episodes_folder(root):
    shutil.rmtree(root / "meta/episodes")


def _missing_data_file(root):
    (root / DATA_1).unlink()


def _missing_video_file(root):
    (root / WRIST_VIDEO).unlink()


# (damage, the line the error must contain). Every line names the file; episode and camera where
# the fault has one.
CASES = {
    "duplicated episode row": (_duplicate_episode_row, f"{EPISODES_FILE}: episode 1: appears in 2 rows"),
    "episode indices with a gap": (_renumber_episode, "meta/episodes: episode indices are not 0..3: missing [2], unexpected [7]"),
    "other camera at the wrong resolution": (
        _wrist_camera_resolution, f"{WRIST_VIDEO}: episode 0: camera wrist_left: frames are 24x24 (h x w), meta/info.json declares 32x32"),
    "video window offset from the data": (
        _shift_video_window, f"{WRIST_VIDEO}: episode 2: camera wrist_left: from_timestamp is 2.700 s, but the file's previous episode ends at 2.400 s"),
    "data timestamps offset": (_offset_data_timestamps, f"{DATA_0}: episode 1: timestamp at frame 0 is 0.500 s, expected frame_index/fps = 0.000 s"),
    "state of the wrong width": (_narrow_state, f"{DATA_0}: episode 1: observation.state holds 13 values in 12 frame(s), meta/info.json declares (14,)"),
    "action of the wrong dtype": (_action_as_float64, f"{DATA_1}: column 'action' holds float64, meta/info.json declares float32"),
    "episode task unknown to tasks.parquet": (
        _task_not_in_tasks_table, f"{EPISODES_FILE}: episode 3: task 'Put the Ball in the Box' is not in meta/tasks.parquet"),
    "rows carry another task_index": (
        _rows_carry_other_task, f"{DATA_0}: episode 2: rows carry task_index [1] (['Stack the Two Blocks']) but meta/episodes lists ['Pick the Cup and Place it on the Plate']"),
    "wrong totals in info.json": (_wrong_totals, "meta/info.json: total_episodes is 5 but the metadata holds 4"),
    "info.json not JSON": (_info_not_json, "meta/info.json: not readable JSON"),
    "stats.json not JSON": (_stats_not_json, "meta/stats.json: not readable JSON"),
    "truncated data parquet": (_truncated_data_file, f"{DATA_0}: episode 0: not a readable parquet file"),
    "truncated episodes parquet": (_truncated_episodes_file, f"{EPISODES_FILE}: not a readable parquet file"),
    "a v2.1 dataset": (_version_2_1, "meta/info.json: codebase_version is v2.1; r2s-eval reads LeRobotDataset v3.0"),
    "no tasks.parquet": (_no_tasks_file, "meta/tasks.parquet: missing"),
    "no meta/episodes": (_no_episodes_folder, "meta/episodes/: missing"),
    "a data file missing": (_missing_data_file, f"{DATA_1}: episode 3: data file is missing"),
    "a video file missing": (_missing_video_file, f"{WRIST_VIDEO}: episode 1: camera wrist_left: video file is missing"),
}


def test_the_valid_dataset_passes(dataset, tmp_path, no_network):
    index, report = ingest_dataset(dataset, "local/test", spec(), tmp_path / "frames")
    assert list(index["episode_index"]) == [0, 1, 2, 3]
    assert list(index["task"]) == ["cup_on_plate", "stack_blocks"] * 2
    assert report["dropped"] == {} and report["frames_usable"] == EPISODES * LENGTH
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == [f"episode_{e:06d}.png" for e in range(4)]
    assert no_network == []


@pytest.mark.parametrize("case", sorted(CASES))
def test_damage_is_named_and_needs_no_network(case, dataset, tmp_path, no_network):
    damage, expected = CASES[case]
    root = Path(shutil.copytree(dataset, tmp_path / "teleop"))
    damage(root)
    with pytest.raises(DatasetValidationError) as err:
        ingest_dataset(root, "local/test", spec(), tmp_path / "frames")
    message = str(err.value)
    assert expected in message, message
    assert message.startswith(f"dataset {root}: ")
    assert no_network == [], f"ingest tried to reach {no_network}"


def test_dropping_keeps_the_sound_episodes(dataset, tmp_path, no_network):
    root = Path(shutil.copytree(dataset, tmp_path / "teleop"))
    _missing_data_file(root)  # episode 3's rows are gone
    _narrow_state(root)  # episode 1's states are too narrow
    index, report = ingest_dataset(root, "local/test", spec(drop_bad_episodes=True), tmp_path / "frames")
    assert list(index["episode_index"]) == [0, 2]
    assert set(report["dropped"]) == {"1", "3"}
    assert report["dropped"]["3"] == [f"{DATA_1}: episode 3: data file is missing"]
    assert not (tmp_path / "frames" / "episode_000001.png").exists()
    # A fault of the whole dataset is never dropped around.
    _wrong_totals(root)
    with pytest.raises(DatasetValidationError, match="total_episodes is 5"):
        ingest_dataset(root, "local/test", spec(drop_bad_episodes=True), tmp_path / "frames2")


def _run_stage(root: Path, tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    world = bundled_world()
    cfg = {"world.cameras": CAMERAS, "world.robot": world["robot"], "world.rig": world["rig"], "calib.camera": "head_left",
           "instructions": {"cup_on_plate": "Pick the Cup and Place it on the Plate"},
           "ingest.repo_id": "local/test", "ingest.min_length": 5, "ingest.max_length": 100,
           "ingest.drop_bad_episodes": False, "ingest.check_videos": True}
    out = tmp_path / "out"
    return subprocess.run(
        [sys.executable, "-m", "r2s_eval.stages.ingest", "--cfg", json.dumps(cfg), "--dataset", str(root),
         "--index", str(out / "episodes.parquet"), "--report", str(out / "report.json"),
         "--frames", str(out / "frames"), *extra],
        capture_output=True, text=True, timeout=300,
    )


def test_stage_prints_one_paragraph_and_keeps_the_traceback_in_the_log(dataset, tmp_path):
    root = Path(shutil.copytree(dataset, tmp_path / "teleop"))
    _info_not_json(root)
    log = tmp_path / "logs" / "ingest.log"
    proc = _run_stage(root, tmp_path, "--log", str(log))
    assert proc.returncode == 1
    assert proc.stderr.startswith("ingest failed: dataset ")
    assert "meta/info.json: not readable JSON" in proc.stderr and "Traceback" not in proc.stderr
    assert f"(details: {log})" in proc.stderr
    text = log.read_text()
    assert "Traceback" in text and "meta/info.json: not readable JSON" in text
    assert not any((tmp_path / "out").iterdir())  # nothing that looks like a result

    plain = _run_stage(root, tmp_path)  # by hand: the paragraph only
    assert plain.returncode == 1 and "Traceback" not in plain.stderr and "not readable JSON" in plain.stderr
    debug = _run_stage(root, tmp_path, "--debug")
    assert debug.returncode == 1 and "Traceback" in debug.stderr
