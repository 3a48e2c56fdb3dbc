"""The twin's camera (``r2s_eval.twin.camera``, applied by ``RealityEnv``): its true lens (OpenCV's
rational model, which the calibrated sim's five coefficients only approximate), drifting exposure
and white balance, motion blur and shot noise; with every effect off, the simulated camera's
bytes."""

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares

from r2s_eval.sim import WorldParams
from r2s_eval.sim.sensor import add_image_noise, distort, distortion_maps
from r2s_eval.twin.camera import (C920_RATIONAL, DRIFT_KNOT_S, TwinCamera, add_sensor_noise, drift_gains,
                                  exposure_substeps)
from r2s_eval.twin.reality import RealityEffects
from tests.helpers.commands import POSES
from tests.helpers.lens import LINE_X, LINE_Y, line_through_lens, project
from tests.helpers.worlds import bundled_env, bundled_twin_env

C920_FIVE = C920_RATIONAL[:5]  # the C920's published five-coefficient calibration
SIZE = (480, 640)


# ----------------------------------------------------------------------------- nominal: the sim's bytes


@pytest.mark.parametrize("params, reality", [
    (WorldParams(), RealityEffects()),
    (WorldParams(image_noise_std=3.0, noise_seed=5), RealityEffects()),
    # An all-zero lens and zero amplitudes are the simulated camera: the same bytes.
    (WorldParams(image_noise_std=3.0, noise_seed=5), RealityEffects(lens_distortion={"head_left": (0.0,) * 8})),
    # The calibrated sim's lens answer alone (the twin with its lens family taken away).
    (WorldParams(noise_seed=5, lens_distortion={"head_left": C920_FIVE}), RealityEffects()),
], ids=["nominal", "additive_noise", "zero_lens", "sim_lens"])
def test_a_twin_camera_without_effects_records_the_simulated_cameras_bytes(params, reality):
    twin = bundled_twin_env("cup_on_plate", params, reality, cameras=("head_left", "wrist_right"))
    sim = bundled_env("cup_on_plate", params, cameras=("head_left", "wrist_right"))
    for env in (twin, sim):
        env.reset(POSES, seed=9)
    commands = np.random.default_rng(1).normal(0.0, 0.05, (3, sim.action_dim))
    for command in commands:
        assert all(np.array_equal(a, b) for a, b in zip(twin.images().values(), sim.images().values()))
        video = np.random.default_rng(2)
        assert np.array_equal(twin.render("head_left", (64, 96), add_noise=True, noise_rng=video),
                              sim.render("head_left", (64, 96), add_noise=True, noise_rng=np.random.default_rng(2)))
        for env in (twin, sim):
            env.step(env.state() + command, images=False)
    assert np.array_equal(twin.data.qpos, sim.data.qpos)
    for env in (twin, sim):
        env.close()


# ----------------------------------------------------------------------------- the true lens


def test_a_straight_line_bows_as_the_rational_lens_predicts():
    K, predicted, measured = line_through_lens(C920_RATIONAL, SIZE)
    np.testing.assert_allclose(measured, predicted[:, 1], atol=0.2)
    # The rational terms bow it less than the five-coefficient C920 model does (the denominator
    # grows with the radius): its ends lie a pixel and more from where that model puts them.
    five = project(K, C920_FIVE, np.c_[LINE_X, np.full_like(LINE_X, LINE_Y)])
    assert np.abs(five[[0, -1], 1] - predicted[[0, -1], 1]).min() > 1.0


def test_the_sims_five_coefficients_approximate_the_true_lens_and_never_reproduce_it():
    """The best five-coefficient answer to the rational lens over a 75 deg wrist camera at 640x480
    (the rays the image shows): close (0.02 px RMS measured) but not exact (0.19 px at worst), while
    the C920's published five coefficients are a few pixels off it."""
    K = bundled_env("cup_on_plate", cameras=()).camera_K("wrist_left", SIZE)
    u, v = np.meshgrid(np.linspace(0, SIZE[1] - 1, 64), np.linspace(0, SIZE[0] - 1, 48))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rays = cv2.undistortPointsIter(np.c_[u.ravel(), v.ravel()][:, None], K, np.asarray(C920_RATIONAL), None, None,
                                   criteria).reshape(-1, 2)
    truth = project(K, C920_RATIONAL, rays)
    fit = least_squares(lambda c: (project(K, c, rays) - truth).ravel(), np.asarray(C920_FIVE), xtol=1e-15,
                        ftol=1e-15)
    left = np.linalg.norm(project(K, fit.x, rays) - truth, axis=1)
    assert 0.005 < np.sqrt(np.mean(left**2)) < 0.05 and left.max() > 0.1
    published = np.linalg.norm(project(K, C920_FIVE, rays) - truth, axis=1)
    assert np.sqrt(np.mean(published**2)) > 1.0


def test_the_twin_records_through_its_lens_after_the_sims_answer_and_its_hypothesis_renders_stay_pinhole():
    reality = RealityEffects(lens_distortion={"head_left": C920_RATIONAL})
    twin = bundled_twin_env("cup_on_plate", WorldParams(), reality, cameras=("head_left", "head_right"))
    sim = bundled_env("cup_on_plate", WorldParams(lens_distortion={"head_left": C920_FIVE}),
                      cameras=("head_left", "head_right"))
    for env in (twin, sim):
        env.reset(POSES, seed=2)
    pinhole = twin.render("head_left")
    assert np.array_equal(pinhole, sim.render("head_left"))  # hypothesis render: clean
    recorded = twin.render("head_left", add_noise=True)
    K = twin.camera_K("head_left")
    assert np.array_equal(recorded, distort(pinhole, distortion_maps(K, C920_RATIONAL, pinhole.shape[:2])))
    assert np.array_equal(recorded, twin.images()["observation.images.head_left"])
    # The sim's five-coefficient answer draws nearly the same image, not the same one.
    answer = sim.render("head_left", add_noise=True)
    assert not np.array_equal(recorded, answer) and np.abs(recorded.astype(int) - answer).mean() < 3
    assert np.array_equal(twin.render("head_right", add_noise=True), twin.render("head_right"))  # no lens there
    # A world carrying a lens answer too records through both, the answer first.
    both = bundled_twin_env("cup_on_plate", WorldParams(lens_distortion={"head_left": C920_FIVE}), reality,
                            cameras=("head_left",))
    both.reset(POSES, seed=2)
    assert np.array_equal(both.render("head_left", add_noise=True),
                          distort(answer, distortion_maps(K, C920_RATIONAL, pinhole.shape[:2])))
    for env in (twin, sim, both):
        env.close()


# ----------------------------------------------------------------------------- exposure, white balance


def test_exposure_and_white_balance_drift_smoothly_within_their_amplitudes():
    dt_s, exposure_rel, balance_rel = 0.1, 0.05, 0.03
    times = np.arange(400) * dt_s  # 40 s: twenty knots
    gains = [drift_gains((5, 9, 0), t, exposure_rel, balance_rel) for t in times]
    exposure = np.array([g[0] for g in gains])
    balance = np.array([g[1] for g in gains])
    assert np.abs(exposure - 1).max() <= exposure_rel and np.abs(balance - 1).max() <= balance_rel + 1e-7
    assert np.all(balance[:, 1] == 1.0)  # white balance holds green
    for series, amplitude in ((exposure, exposure_rel), (balance[:, 0], balance_rel), (balance[:, 2], balance_rel)):
        assert np.ptp(series) > amplitude  # it wanders over the range, not a fixed gain
        # Smooth: a knot-to-knot swing of at most 2 amplitudes over DRIFT_KNOT_S, at most 15/8 of
        # its mean slope (smootherstep), so at most 0.19 amplitudes per 0.1 s step.
        assert np.abs(np.diff(series)).max() <= 2 * amplitude * 15 / 8 * dt_s / DRIFT_KNOT_S + 1e-7
        assert np.abs(np.diff(series, 2)).max() < 0.05 * amplitude  # no kinks
    again = [drift_gains((5, 9, 0), t, exposure_rel, balance_rel) for t in times[::-1]][::-1]
    assert np.array_equal(exposure, [g[0] for g in again])  # the same gains in any order
    other_episode = np.array([drift_gains((5, 10, 0), t, exposure_rel, balance_rel)[0] for t in times])
    other_camera = np.array([drift_gains((5, 9, 1), t, exposure_rel, balance_rel)[0] for t in times])
    assert not np.allclose(other_episode, exposure) and not np.allclose(other_camera, exposure)


def test_a_drifting_camera_records_the_scene_times_its_gains_the_same_at_every_render():
    reality = RealityEffects(exposure_drift_rel=0.05, white_balance_drift_rel=0.03)
    env = bundled_twin_env("cup_on_plate", WorldParams(noise_seed=5), reality, cameras=("head_left",))
    env.reset(POSES, seed=9)
    for _ in range(7):
        env.step(env.state(), images=False)
    clean = env.render("head_left").astype(float)
    recorded = env.render("head_left", add_noise=True)
    assert np.array_equal(recorded, env.render("head_left", add_noise=True))
    exposure, balance = drift_gains((5, 9, 0), 7 * env.control_dt_s, 0.05, 0.03)
    unclipped = clean * exposure * balance < 254
    for c in range(3):
        ratio = recorded[..., c][unclipped[..., c]].sum() / clean[..., c][unclipped[..., c]].sum()
        assert ratio == pytest.approx(exposure * balance[c], abs=2e-3)
    env.reset(POSES, seed=10)  # another episode: other gains
    for _ in range(7):
        env.step(env.state(), images=False)
    assert not np.array_equal(env.render("head_left", add_noise=True), recorded)
    env.close()


def test_the_twins_effects_act_on_what_the_sims_lens_answer_shows():
    """Pinhole -> the calibrated sim's lens answer -> the twin's camera: a twin that keeps the
    sim's lens (its lens family taken away) drifts the image the sim records."""
    params = WorldParams(noise_seed=5, lens_distortion={"head_left": C920_FIVE})
    reality = RealityEffects(exposure_drift_rel=0.05, white_balance_drift_rel=0.03)
    twin = bundled_twin_env("cup_on_plate", params, reality, cameras=("head_left",))
    sim = bundled_env("cup_on_plate", params, cameras=("head_left",))
    for env in (twin, sim):
        env.reset(POSES, seed=9)
        env.step(env.state(), images=False)
    camera = TwinCamera({}, 0.05, 0.03, 0.0, 0.0)
    expected = camera.record(sim.render("head_left", add_noise=True), "head_left", drift_key=(5, 9, 0),
                             time_s=sim.control_dt_s)
    assert np.array_equal(twin.render("head_left", add_noise=True), expected)
    for env in (twin, sim):
        env.close()


# ----------------------------------------------------------------------------- motion blur


def test_motion_blur_smears_what_moves_and_leaves_the_still_scene_alone():
    assert exposure_substeps(50, 0.002, 0.0) == ()
    assert exposure_substeps(50, 0.002, 0.02) == (41, 43, 45, 47, 49)  # the last 20 ms, 5 centres
    assert exposure_substeps(50, 0.002, 1.0)[-1] <= 50  # never longer than the period
    blurred = bundled_twin_env("cup_on_plate", reality=RealityEffects(exposure_time_s=0.02), cameras=("head_left",))
    sharp = bundled_env("cup_on_plate", cameras=("head_left",))
    for e in (blurred, sharp):
        e.reset(POSES, seed=3)
    assert np.array_equal(blurred.render("head_left", add_noise=True), sharp.render("head_left", add_noise=True))
    home = sharp.state().copy()
    swing = home.copy()
    swing[7] += 0.8  # the right arm's base turns and its shoulder lifts
    swing[8] -= 0.5
    for e in (blurred, sharp):
        e.step(home + 0.5 * (swing - home), images=False)
    previous = sharp.render("head_left", add_noise=True)
    for e in (blurred, sharp):
        e.step(swing, images=False)
    assert np.array_equal(blurred.data.qpos, sharp.data.qpos)  # blur is the camera's: same physics
    frame = blurred.render("head_left", add_noise=True).astype(int)
    now = sharp.render("head_left", add_noise=True)
    difference = np.abs(frame - now).max(axis=-1)
    still = np.all(previous == now, axis=-1)  # the same at both ends of the period
    assert still.sum() > 0.8 * still.size and (~still).sum() > 300
    assert (difference[still] > 1).mean() < 0.01
    assert difference[~still].mean() > 3
    assert np.array_equal(blurred.render("head_left", add_noise=True), frame)  # same pixels when rendered again
    blurred.set_object_pose("cup", blurred.object_state("cup")["pos_world_m"] + [0, 0, 0.001])
    # A set scene has no motion to blur: sharp.
    assert np.array_equal(blurred.render("head_left", add_noise=True), blurred.render("head_left"))
    blurred.step(swing, images=False)
    blurred.reset(POSES, seed=3)  # a new episode starts still
    assert np.array_equal(blurred.render("head_left", add_noise=True), blurred.render("head_left"))
    for e in (blurred, sharp):
        e.close()


# ----------------------------------------------------------------------------- shot noise


def test_shot_noise_variance_grows_with_intensity():
    rng = np.random.default_rng(0)
    std, shot = 2.0, 0.5
    for level in (20.0, 60.0, 120.0, 180.0):
        image = np.full((256, 256, 3), level, dtype=np.float32)
        noisy = add_sensor_noise(image, rng, std, shot).astype(float)
        # Truncating to uint8 adds a uniform quantisation error: variance 1/12, mean -0.5.
        assert noisy.var() == pytest.approx(std**2 + shot * level + 1 / 12, rel=0.03)
        assert noisy.mean() == pytest.approx(level - 0.5, abs=0.1)
    same = add_sensor_noise(np.full((8, 8, 3), 90, np.uint8), np.random.default_rng(3), std, 0.0)
    assert np.array_equal(same, add_image_noise(np.full((8, 8, 3), 90, np.uint8), np.random.default_rng(3), std))


def test_a_twin_with_shot_noise_records_it_from_the_steps_generator():
    env = bundled_twin_env("cup_on_plate", WorldParams(image_noise_std=1.0, noise_seed=4),
                           RealityEffects(shot_noise_var_per_level=0.5), cameras=("head_left",))
    env.reset(POSES, seed=9)
    clean = env.render("head_left")
    recorded = env.render("head_left", add_noise=True)
    assert np.array_equal(recorded, env.render("head_left", add_noise=True))
    rng = np.random.default_rng([4, 9, 0, 0])
    assert np.array_equal(recorded, add_sensor_noise(clean, rng, 1.0, 0.5))
    # A video frame draws its noise from its own generator, the observations' stream untouched.
    video = env.render("head_left", add_noise=True, noise_rng=np.random.default_rng(8))
    assert np.array_equal(video, add_sensor_noise(clean, np.random.default_rng(8), 1.0, 0.5))
    env.close()
