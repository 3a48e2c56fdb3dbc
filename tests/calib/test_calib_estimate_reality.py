"""The initial-pose estimate where reality is no simulator: a frame recorded through a lens, a mug
whose handle the model lacks, a wooden table that passes a block's colour rule, and the twin a
simulator cannot copy (``real=twin_unmodelled``)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import r2s_eval  # noqa: F401  (sets the headless GL backend before mujoco loads)
from r2s_eval.calib import make_segmenter
from r2s_eval.calib.estimate import yaw_error_rad
from tests.helpers.worlds import bundled_env

CAMERA = "head_left"


def _errors_mm(env, truth, estimates):
    return {n: 1000 * np.hypot(estimates[n].x_m - truth[n][0], estimates[n].y_m - truth[n][1]) for n in truth}


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
    world = _without_handle(cfg["world"])  # the robustness is for a handle the world does not state
    twin = make_reality_env(task, world, params, reality, cameras=(CAMERA,), suite_cfg=cfg["suite"])
    sim = make_env(task, world, cameras, cameras=())
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


def _without_handle(world: dict) -> dict:
    """The world with its cup's stated handle dropped (the world's plain cup)."""
    from r2s_eval.sim.objects import HANDLE_DIMS

    world = copy.deepcopy(world)
    for obj in world["objects"].values():
        for key in HANDLE_DIMS:
            obj["dims"].pop(key, None)
    return world


def test_a_mug_whose_handle_the_world_states_is_located_with_its_yaw(unmodelled_twin):
    """The unmodelled experiment's world states the lab's mug (its handle measured to the
    millimetre): the calibrated sim's cup is a mug, so the estimate searches its yaw by rendering,
    which the round cup never had, and even the plain estimate is no longer pulled by the handle."""
    from r2s_eval.calib.episodes import estimate_frame, frame_segmenter
    from r2s_eval.sim.build import make_env
    from r2s_eval.twin.reality import make_reality_env

    cfg, params, reality, cameras = unmodelled_twin
    calib = cfg["calib"]
    twin = make_reality_env("cover_ball", cfg["world"], params, reality, cameras=(CAMERA,), suite_cfg=cfg["suite"])
    sims = {"mug": make_env("cover_ball", cfg["world"], cameras, cameras=()),
            "cup": make_env("cover_ball", _without_handle(cfg["world"]), cameras, cameras=())}
    assert [sims[k].task.yaw_symmetry("cup") for k in ("mug", "cup")] == [1, 0]
    rng = np.random.default_rng(2)
    xy, yaw = [], []
    for seed in range(4):
        image = twin.reset(twin.sample_initial_poses(rng), seed=seed)[f"observation.images.{CAMERA}"]
        truth = twin.object_poses()["cup"]["planar"]
        est = estimate_frame(image, sims["mug"], frame_segmenter(sims["mug"], calib), calib)["cup"]
        xy.append(1000 * np.hypot(est.x_m - truth[0], est.y_m - truth[1]))
        yaw.append(np.rad2deg(yaw_error_rad(est.yaw_rad, truth[2], 1)))
    for env_ in (twin, *sims.values()):
        env_.close()
    # Measured (4 upturned mugs, cover_ball): 0.4-2.7 mm, yaw 0.4-4.0 deg.
    assert np.median(xy) < 5.0 and np.median(yaw) < 10.0, (xy, yaw)
