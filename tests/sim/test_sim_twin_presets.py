"""The twin's presets of the ``real`` group: ``real=twin_unmodelled``, the twin a simulator cannot
copy (the lab preset's errors, a webcam's camera and hobby servos), composes with the reference
magnitudes of ``r2s_eval.twin.camera`` and ``r2s_eval.twin.servos`` and draws effects within
them."""

from __future__ import annotations

import numpy as np

from r2s_eval.config import compose_config
from r2s_eval.paths import CONF_DIR
from r2s_eval.sim.robot import world_robot
from r2s_eval.twin.camera import C920_RATIONAL
from r2s_eval.twin.perturb import TwinMagnitudes, reality_rng, sample_reality_effects


def test_the_unmodelled_twin_is_the_lab_twin_with_a_webcam_and_hobby_servos():
    cfg = compose_config(CONF_DIR, "smoke", ["real=twin_unmodelled"])
    lab = compose_config(CONF_DIR, "smoke", ["real=twin_lab"])["real"]["twin"]["magnitudes"]
    magnitudes = cfg["real"]["twin"]["magnitudes"]
    assert cfg["real"]["source"] == "twin"
    assert {k: magnitudes[k] for k in lab} == lab  # the lab preset's cameras, light and paint
    assert magnitudes["camera_pos_m"] == 0.03 and np.isclose(magnitudes["camera_rot_rad"], np.deg2rad(3.0))
    assert tuple(magnitudes["lens_distortion"]) == C920_RATIONAL and magnitudes["lens_spread_rel"] == 0.1
    assert {k: magnitudes[k] for k in ("exposure_drift_rel_max", "white_balance_drift_rel_max", "exposure_time_s_max",
                                       "shot_noise_var_per_level_max", "gripper_weakness_rel")} == {
        "exposure_drift_rel_max": 0.05, "white_balance_drift_rel_max": 0.03, "exposure_time_s_max": 0.02,
        "shot_noise_var_per_level_max": 0.05, "gripper_weakness_rel": 0.5}
    assert list(magnitudes["latency_s_range"]) == [0.1, 0.2] and np.isclose(magnitudes["backlash_rad"], np.deg2rad(1.0))
    # A group of `real` sets no calib or teleop keys: the lens fit and the recorder's codec stay the
    # experiment's to set.
    assert cfg["calib"]["cameras"]["board"]["intrinsics"] is False
    assert cfg["teleop"]["video"] == compose_config(CONF_DIR, "smoke")["teleop"]["video"]
    with_lens = compose_config(CONF_DIR, "smoke", ["real=twin_unmodelled", "calib.cameras.board.intrinsics=true"])
    assert with_lens["calib"]["cameras"]["board"]["intrinsics"] is True


def test_the_unmodelled_twin_draws_its_effects_within_the_references():
    cfg = compose_config(CONF_DIR, "smoke", ["real=twin_unmodelled"])
    robot = world_robot(cfg["world"])
    magnitudes = TwinMagnitudes(**cfg["real"]["twin"]["magnitudes"])
    for seed in range(5):
        reality = sample_reality_effects(reality_rng(seed), magnitudes, robot=robot)
        assert set(reality.lens_distortion) == set(robot.camera_names)
        for lens in reality.lens_distortion.values():  # each unit within 10 % of the C920's
            assert np.all(np.abs(np.subtract(lens, C920_RATIONAL)) <= 0.1 * np.abs(C920_RATIONAL) + 1e-12)
        assert 0 <= reality.exposure_drift_rel <= 0.05 and 0 <= reality.white_balance_drift_rel <= 0.03
        assert 0 <= reality.exposure_time_s <= 0.02 and 0 <= reality.shot_noise_var_per_level <= 0.05
        assert 0.1 <= reality.latency_s <= 0.2 and 0 <= reality.backlash_rad <= np.deg2rad(1.0)
        assert 0.5 <= reality.gripper_strength_scale <= 1.0
