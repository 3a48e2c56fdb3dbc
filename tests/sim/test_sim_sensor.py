"""The simulated camera (``r2s_eval.sim.sensor``): the world's lens (the calibrated sim's answer to a
lab camera's, OpenCV's five coefficients) and its pixel noise; a world without a lens records
today's bytes. The twin's own camera effects: ``test_sim_twin_camera.py``."""

import dataclasses
import hashlib
import json

import cv2
import numpy as np
import pytest

from r2s_eval.errors import ConfigError
from r2s_eval.sim import WorldParams, load_world_params
from r2s_eval.sim.build import check_world_params
from r2s_eval.sim.sensor import (add_image_noise, checked_coefficients, distort, distortion_maps, through_lens,
                                 undistorted, undistorted_coverage)
from tests.helpers.commands import POSES
from tests.helpers.lens import LINE_X, line_through_lens
from tests.helpers.worlds import bundled_env, bundled_world

# A Logitech C920's OpenCV calibration at 640x480: (k1, k2, p1, p2, k3), as a board calibration
# of a lab's camera gives the calibrated sim its lens.
C920_DISTORTION = (0.121, -0.262, 0.0, 0.0, 0.103)


def _rendered_as_before(env, camera: str, size=None) -> np.ndarray:
    """What ``render(camera, add_noise=True)`` returned before the camera model: the pinhole image
    plus ``add_image_noise`` from the (noise seed, episode seed, step, camera) generator."""
    size_hw = size or env.image_size
    renderer = env.renderer(size_hw)
    renderer.update_scene(env.data, camera=camera)
    rgb = renderer.render()
    if env.params.image_noise_std > 0:
        rng = np.random.default_rng([*env._noise_key, env.steps, env.robot.camera_names.index(camera)])
        rgb = add_image_noise(rgb, rng, float(env.params.image_noise_std))
    return rgb


# ----------------------------------------------------------------------------- nominal: today's bytes


@pytest.mark.parametrize("params", [
    WorldParams(),
    WorldParams(image_noise_std=3.0, noise_seed=5),
    # An all-zero lens and zero amplitudes are a pinhole camera: the same bytes as none.
    WorldParams(image_noise_std=3.0, noise_seed=5, lens_distortion={"head_left": (0.0,) * 5}),
], ids=["nominal", "additive_noise", "zero_lens"])
def test_a_camera_without_effects_records_todays_bytes(params):
    env = bundled_env("cup_on_plate", params=params, cameras=("head_left", "wrist_right"))
    env.reset(POSES, seed=9)
    for step in range(3):
        for camera in env.cameras:
            assert np.array_equal(env.render(camera, add_noise=True), _rendered_as_before(env, camera))
        env.step(env.state(), images=False)
    env.close()


# ----------------------------------------------------------------------------- lens


def test_a_straight_line_bows_as_the_c920_coefficients_predict():
    _, predicted, measured = line_through_lens(C920_DISTORTION)
    np.testing.assert_allclose(measured, predicted[:, 1], atol=0.2)
    # It bows: its ends lie 12 px nearer the centre row than its middle (a pinhole keeps it straight).
    middle = len(LINE_X) // 2
    bow_px = measured[0] - measured[middle]
    assert 11 < bow_px < 14 and measured[-1] - measured[middle] == pytest.approx(bow_px, abs=0.1)


def test_undistorting_gives_back_the_pinhole_image():
    size = (480, 640)
    K = bundled_env("cup_on_plate", cameras=()).camera_K("wrist_left", size)
    coefficients = np.asarray(C920_DISTORTION)
    # Blobs on a grid over the image's inner 70 %: their centres go where the lens takes them and
    # come back where they were.
    v, u = np.mgrid[0:size[0], 0:size[1]].astype(float)
    centres = [(uc, vc) for uc in np.linspace(0.15, 0.85, 8) * size[1] for vc in np.linspace(0.15, 0.85, 6) * size[0]]
    pinhole = np.zeros(size)
    for uc, vc in centres:
        pinhole += 250 * np.exp(-((u - uc) ** 2 + (v - vc) ** 2) / (2 * 2.0**2))
    pinhole = np.repeat(np.round(pinhole).astype(np.uint8)[:, :, None], 3, axis=2)
    distorted = distort(pinhole, distortion_maps(K, C920_DISTORTION, size))
    undistorted = cv2.undistort(distorted, K, coefficients)

    def centroids(image):
        out = []
        for uc, vc in centres:
            win = (slice(int(vc) - 12, int(vc) + 13), slice(int(uc) - 12, int(uc) + 13))
            w = image[..., 0][win].astype(float)
            out.append(((w * u[win]).sum() / w.sum(), (w * v[win]).sum() / w.sum()))
        return np.asarray(out)

    truth = np.asarray(centres)
    assert np.abs(centroids(undistorted) - truth).max() < 0.1  # px
    moved, _ = cv2.projectPoints(np.c_[(truth - K[:2, 2]) / np.diag(K)[:2], np.ones(len(truth))],
                                 np.zeros(3), np.zeros(3), K, coefficients)
    moved = moved[:, 0]
    assert np.abs(moved - truth).max() > 3  # the lens did move them, to where its model says
    assert np.abs(centroids(distorted) - moved).max() < 0.2

    # A rendered scene: undistorting the recorded image brings it back to the pinhole render
    # (bilinear twice blurs its edges: compared on average, away from the border).
    env = bundled_env("cup_on_plate", WorldParams(lens_distortion={"wrist_left": C920_DISTORTION}), cameras=())
    env.reset(POSES, seed=1)
    clean = env.render("wrist_left", size=size).astype(int)
    recorded = env.render("wrist_left", size=size, add_noise=True)
    env.close()
    inner = (slice(size[0] // 8, -size[0] // 8), slice(size[1] // 8, -size[1] // 8))
    before = np.abs(recorded.astype(int) - clean)[inner].mean()
    after = np.abs(cv2.undistort(recorded, K, coefficients).astype(int) - clean)[inner].mean()
    assert before > 0.8 and after < 0.5 * before


def test_undistorted_takes_a_recorded_frame_back_to_its_pinhole_image():
    # The helper the calibration sees recorded frames through: undistorted(through_lens(image))
    # gives the image back away from the border (bilinear twice blurs it a little).
    size = (480, 640)
    K = bundled_env("cup_on_plate", cameras=()).camera_K("head_left", size)
    v, u = np.mgrid[0:size[0], 0:size[1]].astype(float)
    grating = 127.5 + 100 * np.sin(2 * np.pi * u / 24) * np.cos(2 * np.pi * v / 30)  # smooth, everywhere textured
    pinhole = np.repeat(np.round(grating).astype(np.uint8)[:, :, None], 3, axis=2)
    recorded = through_lens(pinhole, K, C920_DISTORTION)
    back = undistorted(recorded, K, C920_DISTORTION)
    inner = (slice(size[0] // 8, -size[0] // 8), slice(size[1] // 8, -size[1] // 8))
    before = np.abs(recorded.astype(int) - pinhole)[inner].mean()
    after = np.abs(back.astype(int) - pinhole)[inner].mean()
    assert before > 10 and after < 0.1 * before, (before, after)  # measured 13.2 and 0.66 (0-255)
    # It is cv2.undistort with the camera's K kept (the edge repeated instead of black corners).
    reference = cv2.undistort(recorded, K, np.asarray(C920_DISTORTION))
    assert np.abs(back.astype(int) - reference)[inner].max() <= 1
    # The pincushion pulls the corners out of the frame: only they are not covered.
    covered = undistorted_coverage(K, C920_DISTORTION, size)
    assert covered[inner].all() and not covered[0, 0] and 0.9 < covered.mean() < 1.0
    # A pinhole lens gives the frame itself: the same bytes, no copy.
    assert undistorted(recorded, K, None) is recorded and undistorted(recorded, K, (0.0,) * 5) is recorded
    assert undistorted_coverage(K, None, size).all()


def test_pixels_no_point_reaches_sample_the_edge_along_their_ray():
    # A strong barrel's polynomial folds back (r (1 - 0.5 r^2) peaks at r = 0.82): the wide
    # camera's outer pixels have no source in the model and repeat the edge they look towards.
    size = (128, 128)
    K = bundled_env("cup_on_plate", cameras=()).camera_K("wrist_left", size)
    x, y = cv2.convertMaps(*distortion_maps(K, (-0.5, 0.0, 0.0, 0.0, 0.0), size), cv2.CV_32FC1)
    assert np.all(np.isfinite(x)) and x.min() >= -1 and x.max() <= 128 and y.min() >= -1 and y.max() <= 128
    assert (x[0, 0], y[0, 0]) == (0, 0) and (x[64, 5], y[64, 5]) == pytest.approx((0, 64), abs=0.05)
    ray = np.array([100, 10]) - K[:2, 2]
    assert (x[10, 100], y[10, 100]) == pytest.approx(K[:2, 2] + ray * K[1, 2] / -ray[1], abs=0.05)


def test_any_world_carrying_a_lens_records_through_it_and_its_hypothesis_renders_stay_pinhole():
    # The calibrated sim records through the lens its board calibration fitted.
    fitted = {"head_left": (0.1, -0.2, 0.001, -0.001, 0.05)}
    env = bundled_env("cup_on_plate", WorldParams(lens_distortion=fitted), cameras=("head_left", "head_right"))
    nominal = bundled_env("cup_on_plate", cameras=("head_left", "head_right"))
    for e in (env, nominal):
        e.reset(POSES, seed=2)
    assert np.array_equal(env.render("head_left"), nominal.render("head_left"))  # hypothesis render: clean
    recorded = env.render("head_left", add_noise=True)
    assert not np.array_equal(recorded, nominal.render("head_left"))
    assert np.array_equal(recorded, env.images()["observation.images.head_left"])
    assert np.array_equal(env.render("head_right", add_noise=True), nominal.render("head_right"))  # no lens
    for e in (env, nominal):
        e.close()


def test_world_params_carry_the_lens_and_name_only_the_worlds_cameras(tmp_path):
    params = WorldParams(lens_distortion={"head_left": C920_DISTORTION})
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"params": dataclasses.asdict(params)}))
    assert load_world_params(path) == params
    world = bundled_world()
    check_world_params(params, world, "params.json")
    with pytest.raises(ConfigError, match="lens_distortion of camera 'ceiling'"):
        check_world_params(WorldParams(lens_distortion={"ceiling": C920_DISTORTION}), world, "params.json")
    with pytest.raises(ConfigError, match="has 4 coefficients"):
        check_world_params(WorldParams(lens_distortion={"head_left": (0.1, 0, 0, 0)}), world, "params.json")
    with pytest.raises(ConfigError, match="5 finite coefficients"):
        checked_coefficients((0.1, float("nan"), 0.0, 0.0, 0.0))


def test_a_video_frame_takes_its_noise_from_the_generator_it_is_given():
    env = bundled_env("cup_on_plate", WorldParams(image_noise_std=2.0, noise_seed=3), cameras=("head_left",))
    env.reset(POSES, seed=4)
    clean = env.render("head_left")
    video = env.render("head_left", add_noise=True, noise_rng=np.random.default_rng(11))
    assert np.array_equal(video, add_image_noise(clean, np.random.default_rng(11), 2.0))
    assert not np.array_equal(video, env.render("head_left", add_noise=True))  # the observations' stream is theirs
    env.close()
