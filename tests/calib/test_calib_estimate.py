"""Initial-pose estimation on frames rendered at known poses (nominal and perturbed worlds)."""

from __future__ import annotations

import numpy as np
import pytest

import r2s_eval  # noqa: F401  (sets the headless GL backend before mujoco loads)
from r2s_eval.calib import CameraModel, InitEstimationError, ObjectGeometry, estimate_initial_poses, make_segmenter
from r2s_eval.calib.estimate import wrap_yaw, yaw_error_rad
from r2s_eval.calib.scene import camera_model, mask_renderer, object_geometries
from tests.helpers.worlds import bundled_env, bundled_twin

CAMERA = "head_left"


@pytest.fixture(scope="module")
def env():
    env = bundled_env("cup_on_plate", cameras=(CAMERA,))
    yield env
    env.close()


def _estimate(env, image, refine=True):
    segmenter = make_segmenter({"type": "hsv"}, {o.name: o.rgba for o in env.task.objects})
    return estimate_initial_poses(
        image, segmenter, camera_model(env, CAMERA), env.table_top_z_m, object_geometries(env),
        render_masks=mask_renderer(env, CAMERA) if refine else None,
    )


def _errors_mm(env, truth, estimates):
    return {n: 1000 * np.hypot(estimates[n].x_m - truth[n][0], estimates[n].y_m - truth[n][1]) for n in truth}


def test_refinement_recovers_nominal_poses(env):
    rng = np.random.default_rng(3)
    worst_raw, worst_refined = 0.0, 0.0
    for _ in range(3):
        truth = env.sample_initial_poses(rng)
        obs = env.reset(truth)
        settled = {n: (p["pos_world_m"][0], p["pos_world_m"][1], p["yaw_rad"]) for n, p in env.object_poses().items()}
        image = obs[f"observation.images.{CAMERA}"]
        raw = _errors_mm(env, settled, _estimate(env, image, refine=False))
        refined_est = _estimate(env, image)
        refined = _errors_mm(env, settled, refined_est)
        worst_raw = max(worst_raw, *raw.values())
        worst_refined = max(worst_refined, *refined.values())
        assert all(e.reproj_error_px < 0.5 for e in refined_est.values())
    # Back-projection alone carries the silhouette's perspective bias; the render-based
    # refinement removes it down to the pixel quantisation of a 128x128 frame.
    assert worst_refined < 4.0, worst_refined
    assert worst_refined < worst_raw


def test_twin_frame_is_located_within_the_calibration_gap(env):
    """The twin's camera sits a few mm/deg off the calibration: errors stay in the cm range."""
    params = bundled_twin(np.random.default_rng(1))
    twin = bundled_env("cup_on_plate", params=params, cameras=(CAMERA,))
    truth = twin.sample_initial_poses(np.random.default_rng(5))
    obs = twin.reset(truth, seed=0)
    settled = {n: (p["pos_world_m"][0], p["pos_world_m"][1], 0.0) for n, p in twin.object_poses().items()}
    errors = _errors_mm(env, settled, _estimate(env, obs[f"observation.images.{CAMERA}"]))
    twin.close()
    assert max(errors.values()) < 30.0, errors


def test_offsets_are_added(env):
    truth = env.sample_initial_poses(np.random.default_rng(0))
    image = env.reset(truth)[f"observation.images.{CAMERA}"]
    segmenter = make_segmenter({"type": "hsv"}, {o.name: o.rgba for o in env.task.objects})
    args = (image, segmenter, camera_model(env, CAMERA), env.table_top_z_m, object_geometries(env))
    base = estimate_initial_poses(*args)
    shifted = estimate_initial_poses(*args, offsets={"cup": [0.01, -0.02, 0.0]})
    assert shifted["cup"].x_m == pytest.approx(base["cup"].x_m + 0.01)
    assert shifted["cup"].y_m == pytest.approx(base["cup"].y_m - 0.02)
    assert shifted["plate"].x_m == pytest.approx(base["plate"].x_m)


def test_missing_object_is_named(env):
    segmenter = make_segmenter({"type": "hsv"}, {o.name: o.rgba for o in env.task.objects})
    blank = np.full((128, 128, 3), 200, np.uint8)
    with pytest.raises(InitEstimationError, match="object 'cup' is not visible"):
        estimate_initial_poses(blank, segmenter, camera_model(env, CAMERA), env.table_top_z_m, object_geometries(env))


def test_backprojection_inverts_projection(env):
    camera = camera_model(env, CAMERA)
    point = np.array([0.05, -0.03, env.table_top_z_m + 0.02])
    uv = camera.project(point)[0]
    assert camera.backproject_to_plane(uv, point[2]) == pytest.approx(point, abs=1e-9)


def test_yaw_symmetry():
    assert wrap_yaw(np.pi / 2 + 0.1, 4) == pytest.approx(0.1)
    assert yaw_error_rad(0.05, np.pi / 2 - 0.05, 4) == pytest.approx(0.1)
    assert yaw_error_rad(1.0, -2.0, 0) == 0.0  # rotationally symmetric: yaw is unobservable


def test_principal_axis_gives_yaw_of_elongated_objects():
    """A synthetic top-down camera looking at a bar rotated by 30 degrees."""
    K = np.array([[100.0, 0, 63.5], [0, 100.0, 63.5], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down, image x = world x
    T[:3, 3] = [0.0, 0.0, 1.0]
    image = np.zeros((128, 128, 3), np.uint8)
    import cv2

    box = cv2.boxPoints(((70.0, 60.0), (40.0, 8.0), -30.0)).astype(np.int32)  # image y is down: -30 deg on screen
    cv2.fillPoly(image, [box], (220, 30, 30))
    segmenter = make_segmenter({"type": "hsv"}, {"bar": (0.85, 0.1, 0.1, 1.0)})
    est = estimate_initial_poses(image, segmenter, CameraModel(K, T), 0.0, [ObjectGeometry("bar", 0.0, yaw_symmetry=2)])
    assert np.rad2deg(est["bar"].yaw_rad) == pytest.approx(30.0, abs=3.0)
    assert est["bar"].x_m == pytest.approx((70.0 - 63.5) / 100.0, abs=0.01)


@pytest.mark.parametrize("task", ["stack_blocks", "block_from_box", "upright_cup", "ball_in_box"])
def test_yaw_of_observable_objects_from_a_twin_frame(task):
    """Blocks (mod 90 deg), the box (mod 180 deg) and a lying cup (full turn: which way its
    opening points) from a twin frame passed through 4:2:0 chroma subsampling, as in video."""
    import cv2

    from r2s_eval.calib.scene import image_renderer

    params = bundled_twin(np.random.default_rng(1))
    twin = bundled_env(task, params=params, cameras=(CAMERA,))
    nominal = bundled_env(task, cameras=())
    segmenter = make_segmenter({"type": "hsv"}, {o.name: o.rgba for o in nominal.task.objects})
    geoms = [g for g in object_geometries(nominal)]
    rng = np.random.default_rng(4)
    errors = []
    for seed in range(3):
        image = twin.reset(twin.sample_initial_poses(rng), seed=seed)[f"observation.images.{CAMERA}"]
        image = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_RGB2YUV_I420), cv2.COLOR_YUV2RGB_I420)
        truth = {n: p["planar"] for n, p in twin.object_poses().items()}
        est = estimate_initial_poses(image, segmenter, camera_model(nominal, CAMERA), nominal.table_top_z_m, geoms,
                                     render_masks=mask_renderer(nominal, CAMERA),
                                     render_image=image_renderer(nominal, CAMERA))
        for g in geoms:
            if g.yaw_symmetry:
                errors.append(np.rad2deg(yaw_error_rad(est[g.name].yaw_rad, truth[g.name][2], g.yaw_symmetry)))
    twin.close()
    nominal.close()
    # Before any offset: the twin's camera is ~1 deg off its calibration. A flipped cup
    # or a block off by a quarter turn's fraction would show up as tens of degrees.
    assert np.median(errors) < 5.0 and max(errors) < 12.0, (task, errors)


def test_a_frame_recorded_through_a_lens_is_located_once_undistorted():
    """A head camera with a strong lens (k1 1.5 at 128 px: edges 1-3 px off the pinhole's) records
    the first frames, with pixel noise. The calibrated sim that knows the lens undistorts them
    (``estimate_frame``: ``pinhole_frame``) and finds the poses as a pinhole camera would; one that
    takes them for pinhole images is off by the lens."""
    from r2s_eval.calib.episodes import estimate_frame, frame_segmenter
    from r2s_eval.calib.scene import pinhole_frame
    from r2s_eval.sim import WorldParams

    lens = {CAMERA: (1.5, 0.0, 0.0, 0.0, 0.0)}
    calib = {"camera": CAMERA, "segmenter": {"type": "hsv"},
             "refine": {"max_iterations": 8, "tolerance_px": 0.25, "supersample": 1, "appearance": True}}
    recorder = bundled_env("cup_on_plate", WorldParams(lens_distortion=lens, image_noise_std=2.0, noise_seed=1),
                           cameras=(CAMERA,))
    sims = {"lens": bundled_env("cup_on_plate", WorldParams(lens_distortion=lens), cameras=()),
            "pinhole": bundled_env("cup_on_plate", cameras=())}
    rng = np.random.default_rng(0)
    errors = {name: [] for name in sims}
    for seed in range(3):
        recorder.reset(recorder.sample_initial_poses(rng), seed=seed)
        truth = {n: p["planar"] for n, p in recorder.object_poses().items()}
        image = recorder.render(CAMERA, add_noise=True)
        assert pinhole_frame(sims["pinhole"], CAMERA, image) is image  # no lens: the frame's own bytes
        for name, sim in sims.items():
            estimates = estimate_frame(image, sim, frame_segmenter(sim, calib), calib)
            errors[name] += _errors_mm(sim, truth, estimates).values()
    for env_ in (recorder, *sims.values()):
        env_.close()
    # Measured (6 objects): median 0.6 mm, worst 1.9 mm with the lens; median 10.5 mm, worst 14.8 mm without.
    assert max(errors["lens"]) < 3.0 and np.median(errors["pinhole"]) > 3 * np.median(errors["lens"]), errors


# ----------------------------------------------------------------------------- what the world does not model


def _disc(centre_uv, radius_px=6.0, size=40, k=8) -> np.ndarray:
    """A soft disc (pixel coverage, k x k supersampled)."""
    v, u = np.mgrid[0:size * k, 0:size * k] / k
    inside = (u - centre_uv[0] + 0.5 / k) ** 2 + (v - centre_uv[1] + 0.5 / k) ** 2 <= radius_px**2
    return inside.reshape(size, k, size, k).mean(axis=(1, 3))


def test_the_overlap_shift_follows_the_body_not_a_handle_the_model_lacks():
    import cv2

    from r2s_eval.calib.estimate import _centroid_and_axis, overlap_shift

    rendered = _disc((20.0, 20.0))
    for shift in [(0.3, -0.7), (2.6, 1.2), (-3.5, 0.2)]:  # a plain shift: what the centroids say
        observed = _disc((20.0 + shift[0], 20.0 + shift[1])) > 0.5
        assert overlap_shift(rendered, observed) == pytest.approx(shift, abs=0.15)
    # The observed mug has a handle, a one-pixel loop beside its body, which the model's cup lacks.
    observed = (_disc((20.4, 19.8)) > 0.5).astype(np.uint8)
    body = _centroid_and_axis(observed)[0] - _centroid_and_axis(rendered)[0]
    cv2.circle(observed, (27, 20), 3, 1, 1)
    centroids = _centroid_and_axis(observed)[0] - _centroid_and_axis(rendered)[0]
    # Measured: the overlap's shift 0.21 px off the body's, the centroids' 0.74 px.
    assert np.linalg.norm(overlap_shift(rendered, observed.astype(bool)) - body) < 0.3
    assert np.linalg.norm(centroids - body) > 0.6


def test_a_colour_rule_that_takes_in_the_table_is_made_more_saturated():
    """A wooden table whose hue lies in a yellow block's rule swallows the block in one blob; with
    a bound on the block's area the rule keeps the saturated block."""
    import cv2

    rng = np.random.default_rng(0)
    grain = cv2.GaussianBlur(rng.normal(0.0, 1.0, (128, 128)).astype(np.float32), (0, 0), 2.0)
    hsv = np.stack([np.full((128, 128), 22.0), 110 + 8 * grain, 190 + 10 * grain], axis=-1)  # tan wood
    hsv[60:72, 40:52] = (27, 245, 230)  # the yellow block, 144 px
    image = cv2.cvtColor(np.clip(hsv, 0, 255).astype(np.uint8), cv2.COLOR_HSV2RGB)
    rgba = {"block": (0.90, 0.80, 0.05, 1.0)}
    plain = make_segmenter({"type": "hsv"}, rgba).segment(image)["block"]
    assert plain.sum() > 10_000  # the table passes the rule: one blob of nearly the whole frame
    bounded = make_segmenter({"type": "hsv"}, rgba, max_area_px={"block": 3 * 144}).segment(image)["block"]
    assert bounded[60:72, 40:52].all() and bounded.sum() == 144
    # A blob within the bound is kept as it is.
    assert np.array_equal(make_segmenter({"type": "hsv"}, rgba, max_area_px={"block": 20_000}).segment(image)["block"],
                          plain)


@pytest.fixture(scope="module")
def unmodelled_twin():
    """The twin of ``real=twin_unmodelled`` (seed 5: its wood passes the yellow block's rule), and
    the calibrated sim's cameras of a perfect calibration (the twin's true poses; no lens, which
    changes little at 128 px)."""
    from r2s_eval.config import compose_config
    from r2s_eval.paths import CONF_DIR
    from r2s_eval.sim import WorldParams
    from r2s_eval.sim.robot import world_robot
    from r2s_eval.twin.perturb import twin_world
    from r2s_eval.twin.reality import RealityEffects

    cfg = compose_config(CONF_DIR, "unmodelled", ["real.twin.seed=5"])
    objects = sorted(cfg["world"]["objects"])
    record = twin_world(cfg["real"]["twin"], objects, world_robot(cfg["world"]))
    params = WorldParams(**record["params"])
    cameras = WorldParams(camera_pos_offset_m=params.camera_pos_offset_m,
                          camera_rot_offset_rad=params.camera_rot_offset_rad)
    return cfg, params, RealityEffects.from_dict(record["reality"]), cameras


@pytest.mark.parametrize("task", ["cup_on_plate", "stack_blocks"])
def test_the_unmodelled_twins_first_frames_are_located_within_5_mm(unmodelled_twin, task):
    """A mug with a handle (cup_on_plate), a wood-grain table that passes the yellow block's colour
    rule (stack_blocks), shadows, distractors: the estimate with the unmodelled experiment's config
    (conf/experiment/unmodelled.yaml) against the one without its robustness (centroids, the yaw over the
    mask's box, the largest blob whatever its size)."""
    from r2s_eval.calib.episodes import estimate_frame, frame_segmenter
    from r2s_eval.sim.build import make_env
    from r2s_eval.twin.reality import make_reality_env

    cfg, params, reality, cameras = unmodelled_twin
    calib = cfg["calib"]
    plain = {**calib, "refine": {**calib["refine"], "match": "centroid", "appearance_window": "box"},
             "segmenter": {**calib["segmenter"], "max_area_factor": 0}}
    twin = make_reality_env(task, cfg["world"], params, reality, cameras=(CAMERA,), suite_cfg=cfg["suite"])
    sim = make_env(task, cfg["world"], cameras, cameras=())
    rng = np.random.default_rng(1)
    xy, yaw = {"robust": [], "plain": []}, {"robust": [], "plain": []}
    for seed in range(4):
        image = twin.reset(twin.sample_initial_poses(rng), seed=seed)[f"observation.images.{CAMERA}"]
        truth = {n: p["planar"] for n, p in twin.object_poses().items()}
        for name, c in (("robust", calib), ("plain", plain)):
            est = estimate_frame(image, sim, frame_segmenter(sim, c), c)
            xy[name] += _errors_mm(sim, truth, est).values()
            yaw[name] += [np.rad2deg(yaw_error_rad(est[n].yaw_rad, truth[n][2], sim.task.yaw_symmetry(n)))
                          for n in truth if sim.task.yaw_symmetry(n)]
    twin.close()
    sim.close()
    assert np.median(xy["robust"]) < 5.0 and max(xy["robust"]) < 8.0, xy
    if yaw["robust"]:
        assert np.median(yaw["robust"]) < 5.0, yaw
    # Measured (8 objects each): cup_on_plate median 0.9 mm, worst 3.1 mm (1.8 and 6.0 mm without the
    # robustness: the mug's handle pulls the centroid); stack_blocks median 0.7 mm, worst 1.7 mm, yaw
    # median 1.6 deg (52 and 119 mm, 9.4 deg without: the yellow block's blob is the table).
    assert max(xy["plain"]) > 1.5 * max(xy["robust"]), (xy, task)
