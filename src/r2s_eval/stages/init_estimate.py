"""Stage: estimate every episode's initial object poses from its first head-camera frame.

Runs in the calibrated (nominal) sim: its camera model is the calibration, its renders are
what the refinement matches. It never sees the twin's parameters or true poses. The per-task
offsets come frozen from ``init_offsets`` (fitted on the held-out calibration episodes,
which are flagged ``calibration`` in the output so no score counts them as test data).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import cv2
import pandas as pd
from tqdm import tqdm

from r2s_eval.calib import InitEstimationError, estimate_initial_poses, make_segmenter
from r2s_eval.stages import _cli
from r2s_eval.stages._world import camera_model, make_env, object_geometries
from r2s_eval.utils.io import write_parquet
from r2s_eval.errors import DataError

log = logging.getLogger("r2s_eval.init")


def mask_renderer(env, camera: str, supersample: int = 1):
    """Render the sim's object masks for planar poses, from the calibrated camera.

    With ``supersample`` k > 1 the masks are rendered at k times the resolution and
    area-averaged back: soft masks (pixel coverage) whose centroid and overlap change
    smoothly with the pose, instead of in whole-pixel steps.
    """
    names = env.task.object_names
    h, w = env.image_size
    k = int(supersample)

    def render(poses):
        env.reset(poses, settle=False, observe=False)  # kinematics only: a pose hypothesis
        labels, label_names = env.render(camera, size=(h * k, w * k), segmentation=True)
        by_name = {n: label for label, n in label_names.items()}
        if k == 1:
            return {n: labels == by_name[n] for n in names}
        return {n: (labels == by_name[n]).reshape(h, k, w, k).mean(axis=(1, 3)) for n in names}

    return render


def image_renderer(env, camera: str):
    """Render the sim's clean RGB frame for planar poses, from the calibrated camera."""

    def render(poses):
        env.reset(poses, settle=False, observe=False)
        return env.render(camera)

    return render


def estimate_episodes(index: pd.DataFrame, frames_dir: str | Path, calib: dict, world: dict,
                      offsets: dict | None = None, desc: str = "init") -> pd.DataFrame:
    """One row per (episode, object): the planar pose estimate (offsets of its task added)."""
    envs, rows = {}, []
    for ep in tqdm(index.itertuples(), total=len(index), desc=desc, mininterval=5):
        if ep.task not in envs:
            env = make_env(ep.task, world, cameras=())
            rgba = {o.name: o.rgba for o in env.task.objects}
            envs[ep.task] = (env, make_segmenter(calib["segmenter"], rgba), camera_model(env, calib["camera"]))
        env, segmenter, camera = envs[ep.task]
        frame_path = Path(frames_dir) / ep.first_frame
        raw = cv2.imread(str(frame_path))
        if raw is None:
            raise DataError(f"episode {ep.episode_index}: cannot read first frame {frame_path}")
        image = cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)
        if image.shape[:2] != env.image_size:
            raise DataError(f"episode {ep.episode_index}: first frame {frame_path} is {image.shape[:2]}, calibration expects {env.image_size}")
        geometries = object_geometries(env)
        try:
            estimates = estimate_initial_poses(
                image,
                segmenter,
                camera,
                env.table_top_z_m,
                geometries,
                render_masks=mask_renderer(env, calib["camera"], int(calib["refine"].get("supersample", 1))),
                max_iterations=calib["refine"]["max_iterations"],
                tolerance_px=calib["refine"]["tolerance_px"],
                offsets=(offsets or {}).get(ep.task),
                render_image=image_renderer(env, calib["camera"]) if calib["refine"].get("appearance", True) else None,
            )
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
    for env, _, _ in envs.values():
        env.close()
    return pd.DataFrame(rows)


def main(args) -> None:
    calib, world = args.cfg["calib"], args.cfg["world"]
    index = pd.read_parquet(args.index)
    fitted = json.loads(Path(args.offsets).read_text())
    started = time.perf_counter()
    table = estimate_episodes(index, args.frames, calib, world, fitted["offsets"])
    s_per_episode = (time.perf_counter() - started) / max(len(index), 1)
    table["calibration"] = table["episode_index"].isin(fitted["calibration_episodes"])
    log.info("median reprojection error %.2f px over %d objects", table["reproj_error_px"].median(), len(table))
    write_parquet(args.out, table, metadata={"stage": "init_estimate", "camera": calib["camera"],
                                             "s_per_episode": s_per_episode})


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--index", required=True)
    p.add_argument("--frames", required=True)
    p.add_argument("--offsets", required=True, help="offsets.json written by init_offsets")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
