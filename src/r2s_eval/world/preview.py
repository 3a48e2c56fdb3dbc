"""A look at a world before a run: every camera at a sampled start of each task, and, given a
dataset, each camera's first recorded frame (the simulation's robot and objects outlined on it)
beside the simulation rendered at the poses the calibration estimates from it, through the
model's cameras or a calibrated sim's.

A wrong camera pose, a wrong unit or a mislabelled object shows at a glance: the estimated poses
are drawn into both images (a dot at each object's centre, a line along its yaw, its name), so
the real frame's objects should sit under the dots and the rendered ones should look the same.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from r2s_eval.calib.episodes import estimate_episodes
from r2s_eval.data import STATE_KEY
from r2s_eval.data.contract import read_metadata
from r2s_eval.data.frames import episode_rows, read_frames
from r2s_eval.errors import DataError
from r2s_eval.sim import Robot, TabletopEnv, WorldParams, world_robot
from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.predicates import centre_m
from r2s_eval.sim.tasks import Task, world_tasks

LABEL_PX = 22  # height of the text band above each image
LABEL_SCALE = 0.5  # the labels' font scale where they fit; a narrower panel gets a smaller font
STARTS_PNG, DATASET_PNG = "starts.png", "dataset.png"  # what ``preview`` writes into its folder
PANEL_PX = 320  # height of a starts.png panel: large enough to judge a camera's pose by
MIN_SHOWN_PX = 256  # smaller frames are shown enlarged, so that the labels and marks stay legible


def _labelled(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` under a band with ``text``, whole: its font shrinks until it fits the width."""
    band = np.full((LABEL_PX, image.shape[1], 3), 255, np.uint8)
    (width, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, LABEL_SCALE, 1)
    scale = LABEL_SCALE * min(1.0, (image.shape[1] - 6) / width)
    cv2.putText(band, text, (3, LABEL_PX - 7), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([band, image])


def _draw_poses(image: np.ndarray, env: TabletopEnv, camera: str, poses: Mapping[str, Sequence[float]]) -> np.ndarray:
    """Each object's planar pose drawn into ``camera``'s image: its centre, its yaw, its name."""
    out = image.copy()
    K = env.camera_K(camera, image.shape[:2])
    T = env.camera_T_world_from_cam(camera)
    scale = image.shape[0] / 256
    for name, (x_m, y_m, yaw_rad) in poses.items():
        z_m = float(centre_m(env, name)[2])
        ends = np.array([[x_m, y_m, z_m], [x_m + 0.04 * np.cos(yaw_rad), y_m + 0.04 * np.sin(yaw_rad), z_m]])
        uv, depth = cam_geom.project_points(ends, K, T)
        if np.any(depth <= 0):
            continue  # behind the camera
        (u0, v0), (u1, v1) = np.round(uv).astype(int)
        cv2.line(out, (u0, v0), (u1, v1), (255, 255, 0), max(1, round(2 * scale)), cv2.LINE_AA)
        cv2.circle(out, (u0, v0), max(2, round(4 * scale)), (255, 255, 0), -1, cv2.LINE_AA)
        cv2.putText(out, name, (u0 + 4, v0 - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35 * max(scale, 1), (255, 255, 255), 1,
                    cv2.LINE_AA)
    return out


def _grid(rows: list[list[np.ndarray]]) -> np.ndarray:
    width = max(sum(im.shape[1] for im in row) for row in rows)
    padded = []
    for row in rows:
        line = np.hstack(row)
        padded.append(np.pad(line, ((0, 4), (0, width - line.shape[1]), (0, 0)), constant_values=255))
    return np.vstack(padded)


def render_starts(tasks: Mapping[str, Task], cameras: Sequence[str], size_hw: tuple[int, int], seed: int,
                  robot: Robot) -> np.ndarray:
    """One row per task, one image per camera: the task at a start sampled from its regions."""
    rows = []
    for i, (key, task) in enumerate(tasks.items()):
        env = TabletopEnv(task, image_size=size_hw, cameras=cameras, robot=robot)
        try:
            poses = env.sample_initial_poses(np.random.default_rng([seed, i]))
            env.reset(object_poses=poses, settle=False, observe=False)
            rows.append([_labelled(_draw_poses(env.render(cam), env, cam, poses), f"{key}: {cam}") for cam in cameras])
        finally:
            env.close()
    return _grid(rows)


def _first_episodes(meta, tasks: Mapping[str, Task]) -> dict[str, int]:
    """The first episode of each task the dataset records (by instruction)."""
    by_instruction = {t.instruction: key for key, t in tasks.items()}
    first: dict[str, int] = {}
    for ep in meta.episodes.sort_values("episode_index").itertuples():
        texts = list(ep.tasks) if not isinstance(ep.tasks, str) else [ep.tasks]
        key = next((by_instruction[t] for t in texts if t in by_instruction), None)
        if key is not None:
            first.setdefault(key, int(ep.episode_index))
    if not first:
        raise DataError(f"dataset {meta.root}: no episode's task is an instruction of the world's tasks "
                        f"{sorted(by_instruction)}")
    return first


def _outlined(image: np.ndarray, env: TabletopEnv, camera: str) -> np.ndarray:
    """``image`` with the simulation's robot and objects outlined on it, as ``camera`` sees them:
    where the recording and the simulated camera agree, the outlines hug what the frame shows."""
    labels, _ = env.render(camera, size=image.shape[:2], segmentation=True)
    # the robot's arms and the objects (0 background, 1 table), through the world's lens of the camera
    drawn = env.lens_image((labels >= 2).astype(np.uint8) * 255, camera) > 127
    edges = drawn & ~(cv2.erode(drawn.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    out = image.copy()
    out[edges] = (0, 255, 255)
    return out


def dataset_beside_sim(tasks: Mapping[str, Task], dataset_root: str | Path, cameras: Sequence[str], calib: dict,
                       world: dict, params: WorldParams | None = None) -> np.ndarray:
    """Per task the dataset records, its first episode: each camera's first frame with the
    simulation outlined on it, beside the simulation as its camera records it at the poses the
    calibration estimates from it (its robot at the recorded first state), in the world ``params``
    (a calibrated sim's world parameters: its cameras and lenses, light and colours, background
    plates; None: the model's)."""
    meta = read_metadata(dataset_root)
    first = _first_episodes(meta, tasks)
    frames = read_frames(meta, [(e, 0) for e in first.values()], [calib["camera"], *cameras])
    rows = []
    with tempfile.TemporaryDirectory(prefix="r2s_eval_preview.") as scratch:
        index = []
        for key, episode in first.items():
            frame = frames[episode, 0, calib["camera"]]
            name = f"episode_{episode:06d}.png"
            cv2.imwrite(str(Path(scratch) / name), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            index.append({"episode_index": episode, "task": key, "first_frame": name})
        estimates = estimate_episodes(pd.DataFrame(index), scratch, calib, world, desc="preview", cameras=params)
    for key, episode in first.items():
        mine = estimates[estimates["episode_index"] == episode]
        poses = {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in mine.itertuples()}
        state = episode_rows(meta, episode, [STATE_KEY])[STATE_KEY][0]
        row = []
        for cam in cameras:
            real = frames[episode, 0, cam]
            factor = max(1, -(-MIN_SHOWN_PX // real.shape[0]))
            shown = cv2.resize(real, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)
            env = TabletopEnv(tasks[key], params, image_size=shown.shape[:2], cameras=(cam,), robot=world_robot(world))
            try:
                env.reset(object_poses=poses, settle=False, observe=False)
                env.pose_robot(state)
                row += [_labelled(_draw_poses(_outlined(shown, env, cam), env, cam, poses),
                                  f"{key} ep {episode}: {cam}, sim outlined"),
                        # as the sim's camera records it: its lens, its background plate, its noise
                        _labelled(_draw_poses(env.render(cam, add_noise=True), env, cam, poses), f"{cam}, simulated")]
            finally:
                env.close()
        rows.append(row)
    return _grid(rows)


def preview(world: dict, out: str | Path, cameras: Sequence[str], size_hw: tuple[int, int], seed: int = 0,
            dataset: str | Path | None = None, calib: dict | None = None, params: WorldParams | None = None) -> Path:
    """Write the preview PNG(s) of ``world`` (a ``world`` config slice); returns the folder written.

    Without ``dataset``, a ``dataset.png`` an earlier call left in ``out`` is removed: the folder
    never shows a recording beside starts that are not its world's."""
    tasks = world_tasks(world)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    starts = render_starts(tasks, cameras, size_hw, seed, world_robot(world))
    cv2.imwrite(str(out / STARTS_PNG), cv2.cvtColor(starts, cv2.COLOR_RGB2BGR))
    if dataset is not None:
        side = dataset_beside_sim(tasks, dataset, cameras, calib, world, params)
        cv2.imwrite(str(out / DATASET_PNG), cv2.cvtColor(side, cv2.COLOR_RGB2BGR))
    else:
        (out / DATASET_PNG).unlink(missing_ok=True)
    return out
