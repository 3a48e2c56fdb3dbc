"""Initial-pose estimates of a dataset's episodes, each from its first head-camera frame, and the
per-task offsets fitted once on its calibration episodes (`calibrate_offsets`)."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.calib.estimate import InitEstimationError, PoseEstimate, estimate_initial_poses
from r2s_eval.calib.offsets import calibration_subset, fit_offsets, median_error_mm, read_measured_poses
from r2s_eval.calib.scene import camera_model, image_renderer, mask_renderer, object_geometries, pinhole_frame
from r2s_eval.calib.segment import Segmenter, finders, make_segmenter
from r2s_eval.errors import DataError
from r2s_eval.sim import WorldParams
from r2s_eval.sim.build import make_env

log = logging.getLogger("r2s_eval.init_offsets")


def estimate_episodes(index: pd.DataFrame, frames_dir: str | Path, calib: dict, world: dict,
                      offsets: dict | None = None, desc: str = "init", cameras: WorldParams | None = None
                      ) -> pd.DataFrame:
    """One row per (episode, object): the planar pose estimate (offsets of its task added), seen
    through the calibrated cameras (``cameras``: world parameters holding their poses and, where
    the calibration fitted them, their lenses; None: the model's). Each first frame is undistorted
    through its camera's lens before it is compared with the pinhole renders
    (``r2s_eval.calib.scene.pinhole_frame``)."""
    envs, rows = {}, []
    for ep in tqdm(index.itertuples(), total=len(index), desc=desc, mininterval=5):
        if ep.task not in envs:
            env = make_env(ep.task, world, cameras, cameras=())
            envs[ep.task] = (env, frame_segmenter(env, calib))
        env, segmenter = envs[ep.task]
        frame_path = Path(frames_dir) / ep.first_frame
        raw = cv2.imread(str(frame_path))
        if raw is None:
            raise DataError(f"episode {ep.episode_index}: cannot read first frame {frame_path}")
        image = cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)
        if image.shape[:2] != env.image_size:
            raise DataError(f"episode {ep.episode_index}: first frame {frame_path} is {image.shape[:2]}, calibration expects {env.image_size}")
        geometries = object_geometries(env)
        try:
            estimates = estimate_frame(image, env, segmenter, calib, (offsets or {}).get(ep.task))
        except InitEstimationError as exc:
            raise InitEstimationError(f"episode {ep.episode_index} ({frame_path}): {exc}") from exc
        for geom in geometries:
            est = estimates[geom.name]
            rows.append(
                {
                    "episode_index": int(ep.episode_index),
                    "task": ep.task,
                    "object": geom.name,
                    "x_m": est.x_m,
                    "y_m": est.y_m,
                    "yaw_rad": est.yaw_rad,
                    "yaw_symmetry": geom.yaw_symmetry,
                    "reproj_error_px": est.reproj_error_px,
                    "iterations": est.iterations,
                    "mask_area_px": est.mask_area_px,
                }
            )
    for env, _ in envs.values():
        env.close()
    return pd.DataFrame(rows)


AREA_SAMPLES = 8  # start states drawn to bound each object's silhouette area (a fixed draw)
MAX_AREA_FACTOR = 3.0  # the hsv segmenter's max_area_factor where the config leaves it out


def frame_segmenter(env, calib: dict) -> Segmenter:
    """The configured segmenter (``calib["segmenter"]``) of ``env``'s task objects. The hsv
    segmenter's ``max_area_factor`` (default ``MAX_AREA_FACTOR``; 0: off) bounds each object's
    blob (``HSVSegmenter``): that many times the most pixels its silhouette covers from
    ``calib["camera"]`` in its task's start states (``silhouette_areas``)."""
    cfg = calib["segmenter"]
    factor = 0.0
    if cfg.get("type", "hsv") == "hsv":
        factor = float(MAX_AREA_FACTOR if cfg.get("max_area_factor") is None else cfg["max_area_factor"])
    max_area = None
    if factor > 0:
        max_area = {name: factor * area for name, area in silhouette_areas(env, calib["camera"]).items()}
    return make_segmenter(cfg, {o.name: o.rgba for o in env.task.objects}, finders(env.task.objects), max_area)


def silhouette_areas(env, camera: str, samples: int = AREA_SAMPLES) -> dict[str, int]:
    """Per task object of ``env``, the most pixels it covers from ``camera`` (at ``env``'s image
    size) over ``samples`` start states drawn from its task's start regions (kinematics only; the
    same draw every time)."""
    rng = np.random.default_rng(0)
    areas = dict.fromkeys(env.task.object_names, 0)
    for _ in range(samples):
        env.reset(env.sample_initial_poses(rng), settle=False, observe=False)
        labels, names = env.render(camera, segmentation=True)
        for label, name in names.items():
            if name in areas:
                areas[name] = max(areas[name], int(np.sum(labels == label)))
    return areas


def estimate_frame(image: np.ndarray, env, segmenter: Segmenter, calib: dict,
                   offsets: dict | None = None) -> dict[str, PoseEstimate]:
    """The planar poses of ``env``'s task objects in ``image`` (RGB, a first frame of
    ``calib["camera"]`` as recorded), ``env`` being the calibrated sim of its task: the frame
    undistorted through the camera's calibrated lens (``pinhole_frame``), then
    ``estimate_initial_poses`` against that camera's pinhole renders (``calib["refine"]``);
    ``offsets``: the task's per-object offsets."""
    camera = calib["camera"]
    refine = calib["refine"]
    return estimate_initial_poses(
        pinhole_frame(env, camera, image),  # as the pinhole renders it is matched with show it
        segmenter,
        camera_model(env, camera),
        env.table_top_z_m,
        object_geometries(env),
        render_masks=mask_renderer(env, camera, int(refine.get("supersample", 1))),
        max_iterations=refine["max_iterations"],
        tolerance_px=refine["tolerance_px"],
        offsets=offsets,
        render_image=image_renderer(env, camera) if refine.get("appearance", True) else None,
        match=refine.get("match", "centroid"),
        appearance_window=refine.get("appearance_window", "box"),
    )


def calibrate_offsets(index: pd.DataFrame, frames_dir: str | Path, calib: dict, world: dict,
                      measured_path: str | None, per_task: int, cameras: WorldParams | None = None) -> dict:
    """The per-task offsets fitted once on the calibration episodes (``per_task`` of each task,
    `calibration_subset`): their poses estimated without offsets against ``measured_path`` (the
    measured poses, parquet or CSV), with the calibration error before and after the offsets.

    Returns what ``offsets.json`` holds. Without measured poses (or with 0 calibration
    episodes) the offsets are zero and ``fitted`` is false.
    """
    subset = calibration_subset(index, per_task)
    episodes = [int(e) for e in subset["episode_index"]]
    result = {"offsets": {}, "calibration_episodes": episodes, "episodes_per_task": per_task,
              "fitted": False, "calibration_error": {}}
    if not (measured_path and episodes):
        log.warning("no measured poses for the calibration episodes: offsets are zero")
        return result
    raw = estimate_episodes(subset, frames_dir, calib, world, offsets=None, desc="init_offsets", cameras=cameras)
    measured = read_measured_poses(measured_path, episodes)
    offsets = fit_offsets(raw, measured)
    before, after = median_error_mm(raw, measured, None), median_error_mm(raw, measured, offsets)
    result.update(offsets=offsets, fitted=True, calibration_error={
        task: {obj: {"xy_mm_median_before": before[task][obj], "xy_mm_median_after": after[task][obj]}
               for obj in before[task]} for task in before})
    for task, objs in offsets.items():
        for obj, (dx, dy, dyaw) in objs.items():
            log.info("%s/%s: offset (%.1f mm, %.1f mm, %.2f deg); calibration error %.1f -> %.1f mm", task, obj,
                     1000 * dx, 1000 * dy, np.rad2deg(dyaw), before[task][obj], after[task][obj])
    return result
