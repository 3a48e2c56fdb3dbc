"""How far off are the initial-pose estimates on the twin a simulator cannot copy?

Builds the reality twin of ``real=twin_unmodelled`` (its seed's world parameters and reality
effects: a C920-like rational lens, a wood-grain table, walls and a poster, shadows, four
distractors on the table's far strip, a mug with a handle, rounded blocks, exposure drift, shot
noise), records ``--episodes`` first frames per task from the camera the estimator uses (the
teleop's start states: the experiment's start regions, reset and settled; each frame encoded and
decoded as the recorder's video, ``teleop.video``, keeps it), and estimates the objects' poses as
``r2s_eval.calib.episodes.estimate_episodes`` does (``estimate_frame``, the experiment's
``calib`` config, no offsets) in the calibrated sim of a perfect camera calibration: the twin's
TRUE camera poses and, for the lens, the twin's rational lens fitted with OpenCV's five
coefficients (least squares over rays spanning the image), as a board take with
``calib.cameras.board.intrinsics`` would give it. The twin's truth is read here only to build those
cameras and to score; the estimator reads nothing of it.

Each variant estimates the same frames:

- ``lens``: the calibrated sim carries the fitted lens (the frames are undistorted through it);
- ``pinhole``: it has none (the frames taken for pinhole images, as before lens handling);
- ``... plain``: the same without the estimate's robustness to what the world does not model
  (``calib.refine.match: centroid``, ``calib.refine.appearance_window: box``,
  ``calib.segmenter.max_area_factor: 0``: the rendered and the observed silhouettes' centroids laid
  over one another, the yaw's luminance compared over the mask's whole box, each colour rule's
  largest blob whatever its size).

Prints, per variant and object, the median and 90th percentile of the xy error (mm) and, for
objects whose yaw is observable, of the yaw error (deg, modulo the object's symmetry), the frames
where the estimate failed (an object not found), and the wall time.

The experiment's ``calib`` config is the robust one (``experiment=unmodelled``: ``match: overlap``,
``appearance_window: object``); another experiment's is whatever it sets.

Run (30 s on 2 cores with the demo's three tasks; 75 s for the seven tasks of ``--experiment
demo_seven --overrides calib.refine.match=overlap calib.refine.appearance_window=object``)::

    MUJOCO_GL=egl python benchmarks/probe_init_on_unmodelled_twin.py [--experiment unmodelled]
        [--tasks cup_on_plate ball_in_box cover_ball] [--episodes 10] [--variants lens pinhole]
"""

from __future__ import annotations

import argparse
import copy
import io
import os
import time
from collections import defaultdict

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from r2s_eval.calib.board import lens_pixels  # noqa: E402
from r2s_eval.calib.episodes import estimate_frame, frame_segmenter  # noqa: E402
from r2s_eval.calib.estimate import InitEstimationError, yaw_error_rad  # noqa: E402
from r2s_eval.config import compose_config  # noqa: E402
from r2s_eval.paths import CONF_DIR  # noqa: E402
from r2s_eval.sim import WorldParams  # noqa: E402
from r2s_eval.sim.build import make_env  # noqa: E402
from r2s_eval.sim.robot import world_robot  # noqa: E402
from r2s_eval.sim.tasks import world_tasks  # noqa: E402
from r2s_eval.twin.perturb import twin_world  # noqa: E402
from r2s_eval.twin.reality import RealityEffects, make_reality_env  # noqa: E402

PLAIN = {"refine": {"match": "centroid", "appearance_window": "box"}, "segmenter": {"max_area_factor": 0}}
VARIANTS = {  # name: (the calibrated sim carries the fitted lens, calib overrides)
    "lens": (True, {}),
    "pinhole": (False, {}),
    # Without the estimate's robustness (as before the unmodelled twin): the centroids laid over one
    # another, the yaw's luminance over the mask's whole box, the colour rules' largest blobs
    # whatever their size.
    "lens plain": (True, PLAIN),
    "pinhole plain": (False, PLAIN),
}


def five_coefficient_lens(rational, K: np.ndarray, size_hw: tuple[int, int]) -> tuple[float, ...]:
    """OpenCV's five coefficients (k1, k2, p1, p2, k3) that best reproduce the rational lens
    ``rational`` (eight) through ``K`` over a grid of rays spanning an image of ``size_hw``."""
    h, w = size_hw
    u, v = np.meshgrid(np.linspace(0.0, w - 1.0, 48), np.linspace(0.0, h - 1.0, 48))
    rays = (np.c_[u.ravel(), v.ravel(), np.ones(u.size)] @ np.linalg.inv(K).T)[:, :2]
    target = lens_pixels(rays, K, rational)
    fit = least_squares(lambda c: (lens_pixels(rays, K, c) - target).ravel(), np.asarray(rational[:5], float))
    return tuple(float(c) for c in fit.x)


def video_round_trip(rgb: np.ndarray, video: dict) -> np.ndarray:
    """``rgb`` as a video of the recorder's settings (``teleop.video``: vcodec, preset, crf, pix_fmt)
    gives it back: encoded alone (an episode's first frame is a key frame) and decoded with PyAV,
    as ingest decodes the first frames."""
    import av

    codec = {"h264": "libx264"}.get(video.get("vcodec", "h264"), video.get("vcodec", "h264"))
    options = {k: str(video[k]) for k in ("preset", "crf", "g") if k in video}
    buffer = io.BytesIO()
    with av.open(buffer, "w", format="mp4") as out:
        stream = out.add_stream(codec, rate=10)
        stream.width, stream.height = rgb.shape[1], rgb.shape[0]
        stream.pix_fmt = video.get("pix_fmt", "yuv420p")
        stream.options = options
        for packet in (*stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")), *stream.encode()):
            out.mux(packet)
    buffer.seek(0)
    with av.open(buffer) as recorded:
        return next(recorded.decode(video=0)).to_ndarray(format="rgb24")


def record_first_frames(task: str, task_index: int, cfg: dict, params: WorldParams, reality: RealityEffects,
                        camera: str, episodes: int) -> list[tuple[np.ndarray, dict]]:
    """``episodes`` first frames of ``task`` in the twin and its true planar poses."""
    env = make_reality_env(task, cfg["world"], params, reality, cameras=(camera,), suite_cfg=cfg.get("suite"))
    rng = np.random.default_rng([int(cfg["seed"]), task_index, 11])  # the teleop's stream of start states
    frames = []
    try:
        for _ in range(episodes):
            obs = env.reset(env.sample_initial_poses(rng), seed=int(rng.integers(2**31)))
            truth = {name: tuple(p["planar"]) for name, p in env.object_poses().items()}
            frames.append((video_round_trip(obs[f"observation.images.{camera}"], cfg["teleop"]["video"]), truth))
    finally:
        env.close()
    return frames


def percentiles(values) -> str:
    values = np.asarray(values, float)
    return f"{np.median(values):6.2f} {np.percentile(values, 90):6.2f}" if len(values) else f"{'-':>6} {'-':>6}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--experiment", default="unmodelled")
    p.add_argument("--overrides", nargs="*", default=[], help="more Hydra overrides")
    p.add_argument("--tasks", nargs="*", help="default: the experiment's")
    p.add_argument("--episodes", type=int, default=10, help="first frames per task")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = p.parse_args()
    started = time.perf_counter()
    cfg = compose_config(CONF_DIR, args.experiment, ["real=twin_unmodelled", *args.overrides])
    world, calib = cfg["world"], cfg["calib"]
    camera = calib["camera"]
    tasks = args.tasks or cfg["tasks"]
    robot = world_robot(world)
    objects = sorted({o.name for t in world_tasks(world).values() for o in t.objects})
    record = twin_world(cfg["real"]["twin"], objects, robot)
    twin_params = WorldParams(**record["params"])
    reality = RealityEffects.from_dict(record["reality"])
    size_hw = (int(world["image_height"]), int(world["image_width"]))

    # The calibrated sim's cameras: the twin's true poses, its lens fitted with five coefficients.
    probe_env = make_env(tasks[0], world, WorldParams(), cameras=())
    K = probe_env.camera_K(camera, size_hw)
    probe_env.close()
    fitted = five_coefficient_lens(reality.lens_distortion[camera], K, size_hw)
    poses = dict(camera_pos_offset_m=twin_params.camera_pos_offset_m,
                 camera_rot_offset_rad=twin_params.camera_rot_offset_rad)
    sims = {True: WorldParams(**poses, lens_distortion={camera: fitted}), False: WorldParams(**poses)}
    print(f"twin seed {cfg['real']['twin']['seed']}, camera {camera} at {size_hw[1]}x{size_hw[0]}: true lens "
          f"{np.round(reality.lens_distortion[camera], 4).tolist()}, fitted {np.round(fitted, 4).tolist()}")
    print(f"distractors {[d[0] for d in reality.distractors]}; tasks {tasks}; {args.episodes} episodes each")

    # Each task's start states from the teleop's stream of it (its index in the experiment's tasks).
    order = list(cfg["tasks"]) + [t for t in tasks if t not in cfg["tasks"]]
    recorded = {task: record_first_frames(task, order.index(task), cfg, twin_params, reality, camera, args.episodes)
                for task in tasks}
    print(f"recorded in {time.perf_counter() - started:.0f} s")

    print(f"{'variant':14s} {'task':14s} {'object':8s} {'xy mm med':>9} {'p90':>6} {'yaw deg med':>11} {'p90':>6} "
          f"{'failed':>6}")
    for variant in args.variants:
        with_lens, changes = VARIANTS[variant]
        variant_calib = copy.deepcopy(calib)
        for group, values in changes.items():
            variant_calib[group].update(values)
        t0 = time.perf_counter()
        for task in tasks:
            env = make_env(task, world, sims[with_lens], cameras=())  # as estimate_episodes makes it
            segmenter = frame_segmenter(env, variant_calib)
            xy, yaw, failed = defaultdict(list), defaultdict(list), 0
            for image, truth in recorded[task]:
                try:
                    estimates = estimate_frame(image, env, segmenter, variant_calib)
                except InitEstimationError:
                    failed += 1
                    continue
                for name, (x, y, yaw_true) in truth.items():
                    est = estimates[name]
                    xy[name].append(1000 * np.hypot(est.x_m - x, est.y_m - y))
                    symmetry = env.task.yaw_symmetry(name)
                    if symmetry:
                        yaw[name].append(np.rad2deg(yaw_error_rad(est.yaw_rad, yaw_true, symmetry)))
            for name in env.task.object_names:
                print(f"{variant:14s} {task:14s} {name:8s} {percentiles(xy[name]):>16} {percentiles(yaw[name]):>18} "
                      f"{failed:6d}", flush=True)
            env.close()
        print(f"{variant}: {time.perf_counter() - t0:.0f} s")
    print(f"wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
