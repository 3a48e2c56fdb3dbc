"""The fixed cameras' poses from the robot's silhouette in a twin's teleop recording, and a fit that
cannot converge refused with the mismatch, the camera and the worst frame."""

from __future__ import annotations

import numpy as np
import pytest

from r2s_eval.calib.cameras import camera_errors, camera_params
from r2s_eval.calib.silhouette import calibrate_from_silhouette, pick_frames
from r2s_eval.errors import ConfigError, DataError
from r2s_eval.sim import WorldParams
from tests.helpers.worlds import bundled_world
from r2s_eval.twin.record import record_teleop

TASKS = ["cup_on_plate"]
SILHOUETTE = {"fit": True, "frames": 16, "stride": 4, "min_frames": 8, "supersample": 2, "blur_px": [4, 2, 1],
              "max_mismatch": 0.3}
TELEOP = {"episodes_per_task": 3, "max_duration_s": 15.0, "keep_failed": True, "max_attempts_factor": 2,
          "operator": {"pause_prob": 0.0, "overshoot_prob": 0.0, "regrasp_prob": 0.0},
          "video": {"vcodec": "h264", "preset": "ultrafast", "crf": 18}}
# A head camera placed from a tape measure, and the wrist camera (which the silhouette cannot see).
TWIN = WorldParams(camera_pos_offset_m={"head_left": (0.012, -0.015, 0.01)},
                   camera_rot_offset_rad={"head_left": (0.015, -0.02, 0.012)}, image_noise_std=1.5, noise_seed=3)


def world() -> dict:
    return {**bundled_world(), "cameras": ["head_left", "wrist_left"]}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("silhouette") / "dataset"
    truth, _ = record_teleop(str(path), TWIN, teleop=TELEOP, world=world(), tasks=TASKS, suite={}, seed=0)
    return path, sorted(int(e) for e in truth["episode_index"].unique())


def test_the_robots_silhouette_places_the_head_camera(recording):
    path, episodes = recording
    record = calibrate_from_silhouette(str(path), episodes, world(), SILHOUETTE, {"type": "hsv"}, TASKS)
    assert set(record["cameras"]) == {"head_left"}
    assert "board take" in record["skipped"]["wrist_left"]
    fitted = camera_errors(WorldParams(**camera_params(record)), TWIN, world(), TASKS, ["head_left"])["head_left"]
    nominal = camera_errors(WorldParams(), TWIN, world(), TASKS, ["head_left"])["head_left"]
    assert nominal["position_mm"] > 20 and nominal["rotation_deg"] > 1.0
    # Nominal (unfitted): 21.7 mm, 1.59 deg. Fitted: 6.80 mm, 0.595 deg with AVX-512 kernels and
    # 7.09 mm, 0.622 deg with OpenBLAS's Haswell (AVX2) kernels under scipy's least squares, as
    # an AMD EPYC (AVX2) measured; 4:2:0 video keeps the fit near 0.5 deg (docs/suite.md). The
    # bounds leave a margin for other processors while a fit must still remove over half the error.
    assert fitted["position_mm"] < 10.0 and fitted["rotation_deg"] < 0.9, (fitted, nominal)
    assert record["cameras"]["head_left"]["mismatch"] < 0.2


def test_a_silhouette_rule_that_finds_no_robot_cannot_converge(recording):
    path, episodes = recording
    blind = world()
    blind["robot"] = {**blind["robot"], "find": {"hue": {"hue_lo": 0, "hue_hi": 179, "sat_min": 254, "val_min": 254}}}
    with pytest.raises(DataError, match=r"dataset .*dataset, camera head_left: the silhouette fit did not converge: "
                                        r"[\d.]+ % of the silhouettes' pixels still disagree .*worst: episode \d+ frame \d+"):
        calibrate_from_silhouette(str(path), episodes, blind, {**SILHOUETTE, "frames": 8, "blur_px": [2]}, {"type": "hsv"},
                                  TASKS)


def test_a_robot_without_a_look_is_a_config_error(recording):
    path, episodes = recording
    plain = world()
    plain["robot"] = {k: v for k, v in plain["robot"].items() if k != "find"}
    with pytest.raises(ConfigError, match=r"world.robot.find.hue"):
        calibrate_from_silhouette(str(path), episodes, plain, SILHOUETTE, {"type": "hsv"}, TASKS)


def test_the_frames_picked_are_the_most_different_poses():
    states = {(0, i): np.array([float(i)]) for i in range(10)}
    assert pick_frames(states, 3) == [(0, 0), (0, 4), (0, 9)]
    assert pick_frames(states, 20) == list(states)
