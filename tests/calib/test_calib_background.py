"""The room behind the robot from a twin's recordings in a furnished room (``r2s_eval.calib.background``):
a plate per fixed camera that brings the calibrated sim's first frames close to the recorded ones,
none for a wrist camera, recordings that never show the room refused, and the sim's camera
recording its robot and objects over a plate."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from r2s_eval.calib.background import fit_plates, plate_errors, shadow_agreement, write_plates
from r2s_eval.data import STATE_KEY
from r2s_eval.data.contract import read_metadata
from r2s_eval.data.frames import episode_rows
from r2s_eval.errors import ConfigError, DataError
from r2s_eval.sim import WorldParams
from r2s_eval.sim.build import check_world_params
from r2s_eval.twin.reality import RealityEffects
from r2s_eval.twin.record import record_teleop
from tests.helpers.commands import POSES
from tests.helpers.worlds import bundled_env, bundled_world

TASKS = ["cup_on_plate"]
TELEOP = {"episodes_per_task": 4, "max_duration_s": 15.0, "keep_failed": True, "max_attempts_factor": 2,
          "operator": {"pause_prob": 0.0, "overshoot_prob": 0.0, "regrasp_prob": 0.0},
          "video": {"vcodec": "h264", "preset": "ultrafast", "crf": 18}}
# A room no world file holds: a wooden table, walls with a poster, shadows, a marker on the far strip.
ROOM = RealityEffects(table_texture=True, walls=True, shadows=True, distractors=(("marker", 0.26, 0.02, 0.5),))
TWIN = WorldParams(image_noise_std=1.0, noise_seed=3)  # the cameras where the model puts them
BACKGROUND = {"fit": True, "frames": 32, "stride": 4, "margin_px": 2, "min_free_frames": 3, "max_unseen": 0.05}


def world() -> dict:
    return {**bundled_world(), "cameras": ["head_left", "wrist_left"]}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("background") / "dataset"
    truth, _ = record_teleop(str(path), TWIN, teleop=TELEOP, world=world(), tasks=TASKS, suite={}, seed=0,
                             reality=ROOM)
    return path, truth


def index_of(truth):
    """Ingest's index of the recording: each episode and its task."""
    return truth.groupby("episode_index", as_index=False).first()[["episode_index", "task"]]


def estimates_of(truth):
    """The initial poses as an estimate would give them (the twin's own, a centimetre off)."""
    return truth.assign(x_m=truth["x_m"] + 0.01)


@pytest.fixture(scope="module")
def plates(recording, tmp_path_factory):
    path, truth = recording
    plates, record = fit_plates(str(path), index_of(truth), estimates_of(truth), world(), WorldParams(), BACKGROUND)
    return write_plates(plates, tmp_path_factory.mktemp("plates")), record


def test_a_fixed_camera_gets_the_room_and_a_wrist_camera_none(plates):
    paths, record = plates
    assert set(paths) == {"head_left"}
    assert "no plate holds it" in record["skipped"]["wrist_left"]
    seen = record["cameras"]["head_left"]
    assert seen["unseen_share"] <= BACKGROUND["max_unseen"]
    assert seen["free_frames_median"] >= BACKGROUND["min_free_frames"]


def test_the_plate_brings_the_sims_first_frames_to_the_recorded_room(recording, plates):
    path, truth = recording
    paths, _ = plates
    errors = plate_errors(str(path), index_of(truth), estimates_of(truth), world(), WorldParams(background_plates=paths),
                          {"frames_per_task": 4})
    head = errors["head_left"]
    assert head["frames"] == 4
    # The sim's plain grey room against a wooden table and plastered walls: most of the image.
    # Measured: 35.3 without the plate, 4.6 with it (0-255; 6.3 with a plate whose objects were left to
    # the median alone, the blue plate of one episode showing through).
    assert head["without_plate"] > 20.0
    assert head["with_plate"] < 0.25 * head["without_plate"], head


def test_the_sims_shadows_fall_where_the_recordings_are_darker_than_the_plate(recording, plates):
    # The twin's key light casts shadows (ROOM); the sim's (calib.appearance.shadows), the same
    # light here, darkens its plate where its arm and objects shade the room mid-episode.
    path, truth = recording
    paths, _ = plates
    args = (str(path), index_of(truth), estimates_of(truth), world())
    assert shadow_agreement(*args, WorldParams(background_plates=paths), {"frames_per_task": 4}) == {}
    head = shadow_agreement(*args, WorldParams(background_plates=paths, shadows=True), {"frames_per_task": 4})["head_left"]
    print(head)
    assert head["frames"] == 12 and head["pixels"] > 100
    assert head["recorded"] < head["unshaded_recorded"] - 0.1
    assert abs(head["recorded"] - head["sim"]) < 0.1
    assert 0.95 < head["unshaded_recorded"] < 1.05


def test_the_record_holds_the_robots_state_at_each_frame_the_plate_is_the_median_of(recording, plates):
    # The sim takes the same median of its own room at them (WorldParams.background_states).
    path, _ = recording
    _, record = plates
    meta = read_metadata(str(path))
    used = record["cameras"]["head_left"]["frames_used"]
    assert len(record["states"]) == len(used) == BACKGROUND["frames"]
    for (episode, frame), state in zip(used, record["states"]):
        recorded = episode_rows(meta, episode, [STATE_KEY])[STATE_KEY][frame]
        assert np.allclose(state, np.asarray(recorded, float))
    assert len({tuple(s) for s in record["states"]}) > BACKGROUND["frames"] // 2  # the arm in many places
    # ...and widens the robot by as many of the plate's pixels (WorldParams.background_margin_px).
    assert record["margin_px"] == BACKGROUND["margin_px"]


def test_recordings_that_never_move_the_arm_away_are_refused(recording):
    path, truth = recording
    at_home = {**BACKGROUND, "stride": 10_000}  # each episode's first frame only: the arms at home
    with pytest.raises(DataError, match=r"dataset .*dataset, camera head_left: [\d.]+ % of the room behind the moving "
                                        r"arm is never seen free of the robot .*calib.background.max_unseen"):
        fit_plates(str(path), index_of(truth), None, world(), WorldParams(), at_home)


def test_the_sim_records_its_robot_and_objects_over_the_plate(tmp_path):
    size = (96, 128)
    plate = np.zeros((*size, 3), np.uint8)
    plate[...] = (200, 30, 160)  # a colour the sim draws nowhere
    cv2.imwrite(str(tmp_path / "head_left.png"), cv2.cvtColor(plate, cv2.COLOR_RGB2BGR))
    params = WorldParams(background_plates={"head_left": str(tmp_path / "head_left.png")})
    plain, plated = bundled_env(image_size=size), bundled_env(params=params, image_size=size)
    try:
        images = []
        for env in (plain, plated):
            env.reset(POSES, seed=0, settle=False, observe=False)
            images.append(env.render("head_left", add_noise=True))
        foreground = plated.foreground_mask("head_left", size)
        assert 0.05 < foreground.mean() < 0.6
        assert np.array_equal(images[0][foreground], images[1][foreground])
        assert np.all(images[1][~foreground] == (200, 30, 160))
        # A camera without a plate, and the hypothesis renders, keep the sim's own surroundings.
        assert np.array_equal(plain.render("wrist_left"), plated.render("wrist_left"))
        assert np.array_equal(plain.render("head_left"), plated.render("head_left"))
    finally:
        plain.close()
        plated.close()


def test_a_plate_that_is_not_there_is_named(tmp_path):
    missing = WorldParams(background_plates={"head_left": str(tmp_path / "nowhere.png")})
    with pytest.raises(ConfigError, match=r"world.json: background_plates: camera 'head_left'.s plate .*nowhere.png "
                                          r"does not exist"):
        check_world_params(missing, bundled_world(), "world.json")
    other = dataclasses.replace(missing, background_plates={"ceiling": str(tmp_path / "nowhere.png")})
    with pytest.raises(ConfigError, match=r"background_plates of camera 'ceiling'"):
        check_world_params(other, bundled_world(), "world.json")


def test_the_world_report_states_the_plates_errors():
    from r2s_eval.report.calibration_report import camera_lines

    report = {"cameras": {"model": {}}, "used": "board",
              "background": {"head_left": {"with_plate": 4.6, "without_plate": 35.3, "frames": 4}}}
    assert ("background head_left: mean colour error of 4 first frames 35.3 with the sim's own surroundings, 4.6 "
            "over the plate from the recordings (0-255)") in camera_lines(report)
    shadows = {"pixels": 11549, "recorded": 0.629, "sim": 0.617, "unshaded_recorded": 1.006, "frames": 12}
    report["background"]["head_left"]["shadows"] = shadows
    report["appearance"] = {"fitted": False, "shadows": True, "twin_shadows": True, "key_light_deg": 2.34}
    lines = camera_lines(report)
    assert ("shadows head_left: where the sim shades the room (11549 px of 12 frames) the recordings are at 63 % of "
            "the plate, the sim at 62 %; elsewhere the recordings at 101 %") in lines
    assert "shadows: sim on, twin on; the key light 2.3 deg from the twin's" in lines
