"""The calibrated sim's light and colours, fitted to the recordings' first frames.

Once the camera and the objects' initial poses are calibrated, an episode's first frame and the
simulation rendered at that episode's first state line up pixel for pixel, so what still differs
is how things look. (The renders are pinhole images: where the calibration fitted the camera's
lens, each first frame is undistorted through it first, ``r2s_eval.calib.scene.pinhole_frame``, and
the pixels it then does not cover are left out.) The fit changes what the twin's appearance family
perturbs and what a room changes: the scene lights' intensity and direction, the table's colour
and each object's colour (``WorldParams`` fields, applied through ``r2s_eval.sim.render_params``),
so every camera of the calibrated sim (the wrist cameras too, which no first frame shows) looks like
the room.

Why these rather than a per-camera colour transform: a global transform cannot give one object
a colour shift another does not have, and it would leave the cameras that were not fitted as
they were. The robot's own colour is left as the model has it: it anchors the brightness (a
brighter light and paler paint would otherwise explain the same pixels).

The residual is the colour difference over the pixels the simulation labels robot, table or an
object (each region shrunk by a pixel, so an edge a fraction of a pixel off does not count),
with a weak pull of every parameter towards the nominal world (``prior``), which keeps
parameters that no frame constrains (an object no first frame shows well) where they were.
Reported: the mean absolute colour error (0-255) over those pixels before and after.

Shadows (``shadows``): the recordings show the arm's and the objects' shadows, which the world
file's lights do not cast. With it the calibrated sim's key light casts them (``WorldParams.shadows``),
and the fit renders them too: a first frame's objects cast their shadows on the table, which
pins the light's direction where the table's shading alone leaves it loose.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from r2s_eval.calib import fitting
from r2s_eval.calib.scene import pinhole_coverage, pinhole_frame
from r2s_eval.data import STATE_KEY
from r2s_eval.data.contract import read_metadata
from r2s_eval.data.frames import episode_rows
from r2s_eval.errors import DataError
from r2s_eval.sim import WorldParams
from r2s_eval.sim.build import make_env
from r2s_eval.sim.render_params import apply_appearance, render_base

log = logging.getLogger("r2s_eval.calib_appearance")

# One unit of each fitted parameter: what a finite-difference step and the prior are measured in.
LIGHT_SCALE_UNIT = 0.1
LIGHT_DIR_UNIT = 0.1
RGB_UNIT = 0.05


@dataclasses.dataclass(frozen=True)
class Frame:
    task: str
    episode: int
    poses: dict[str, tuple[float, float, float]]
    state: np.ndarray
    image: np.ndarray  # RGB, the calibration camera's first frame


def appearance_frames(index: pd.DataFrame, frames_dir: str | Path, estimates: pd.DataFrame, dataset: str,
                      per_task: int) -> list[Frame]:
    """The first frames of ``per_task`` episodes of each task (ingest's index order) with their
    estimated object poses and first recorded state."""
    meta = read_metadata(dataset)
    frames = []
    for task, rows in index.groupby("task", sort=True):
        for ep in rows.head(per_task).itertuples():
            path = Path(frames_dir) / ep.first_frame
            raw = cv2.imread(str(path))
            if raw is None:
                raise DataError(f"episode {ep.episode_index}: cannot read first frame {path}")
            est = estimates[estimates["episode_index"] == ep.episode_index]
            if est.empty:
                raise DataError(f"episode {ep.episode_index}: no initial-pose estimate")
            state = np.asarray(episode_rows(meta, int(ep.episode_index), [STATE_KEY])[STATE_KEY][0], float)
            frames.append(Frame(str(task), int(ep.episode_index),
                                {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in est.itertuples()}, state,
                                cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)))
    return frames


class AppearanceModel:
    """The calibrated sim (cameras, poses) of each frame's task, whose look a parameter vector sets."""

    def __init__(self, frames: Sequence[Frame], world: Mapping, params: WorldParams, camera: str):
        self.frames, self.camera = list(frames), camera
        nominal_look = dataclasses.replace(params, light_intensity_scale=1.0, light_dir_offset=(0.0, 0.0, 0.0),
                                           table_rgb_offset=(0.0, 0.0, 0.0), object_rgb_offset={})
        self.envs, self.bases = {}, {}
        for task in sorted({f.task for f in frames}):
            env = make_env(task, world, nominal_look, cameras=())
            self.envs[task] = env
            self.bases[task] = render_base(env.model, env.robot.table_geom, env.task.objects)
        self.objects = sorted({o for env in self.envs.values() for o in env.task.object_names})
        self.params = params
        # The renders are pinhole images: each frame is compared as the calibrated camera's pinhole
        # would show it (undistorted through its lens; the same frame without one).
        self.frames = [dataclasses.replace(f, image=pinhole_frame(self.envs[f.task], camera, f.image))
                       for f in self.frames]
        self.masks = [self._regions(f) for f in self.frames]

    def _regions(self, frame: Frame) -> np.ndarray:
        """The pixels that count: labelled robot, table or object, each region shrunk by a pixel,
        where the recorded frame covers them."""
        env = self.envs[frame.task]
        self._pose(frame)
        labels, _ = env.render(self.camera, size=frame.image.shape[:2], segmentation=True)
        keep = np.zeros(labels.shape, bool)
        for label in np.unique(labels):
            if label == 0:
                continue  # background: the room beyond the table, which the world does not model
            region = cv2.erode((labels == label).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            keep |= region
        # Pixels the undistorted frame does not cover (a lens's corners) repeat its edge: left out.
        return keep & pinhole_coverage(env, self.camera, labels.shape)

    def _pose(self, frame: Frame) -> None:
        env = self.envs[frame.task]
        env.reset(frame.poses, settle=False, observe=False)
        env.pose_robot(frame.state)

    def world_params(self, x: np.ndarray) -> WorldParams:
        objects = {name: tuple(float(v) for v in RGB_UNIT * x[7 + 3 * i: 10 + 3 * i]) for i, name in enumerate(self.objects)}
        return dataclasses.replace(
            self.params, light_intensity_scale=float(1.0 + LIGHT_SCALE_UNIT * x[0]),
            light_dir_offset=tuple(float(v) for v in LIGHT_DIR_UNIT * x[1:4]),
            table_rgb_offset=tuple(float(v) for v in RGB_UNIT * x[4:7]), object_rgb_offset=objects)

    def size(self) -> int:
        return 7 + 3 * len(self.objects)

    def renders(self, params: WorldParams) -> list[np.ndarray]:
        for task, env in self.envs.items():
            apply_appearance(env.model, self.bases[task], params)
        out = []
        for frame in self.frames:
            self._pose(frame)
            out.append(self.envs[frame.task].render(self.camera, size=frame.image.shape[:2]))
        return out

    def residual(self, params: WorldParams) -> np.ndarray:
        return np.concatenate([((r.astype(np.float32) - f.image.astype(np.float32)) / 255.0)[m].ravel()
                               for r, f, m in zip(self.renders(params), self.frames, self.masks)])

    def mean_abs_error(self, params: WorldParams) -> float:
        """Mean absolute colour error (0-255) over the counted pixels."""
        return float(255.0 * np.mean(np.abs(self.residual(params))))

    def close(self) -> None:
        for env in self.envs.values():
            env.close()


def fit_appearance(model: AppearanceModel, prior: float) -> tuple[WorldParams, dict]:
    """The light and colours that make the renders look like the frames (module docstring)."""
    n_pixels = sum(int(m.sum()) for m in model.masks)
    if n_pixels == 0:
        raise DataError("the appearance fit has no pixel to compare: no first frame shows the scene")
    weight = float(prior) * np.sqrt(n_pixels * 3)  # the prior's pull relative to the pixels' evidence

    def residuals(x):
        return np.r_[model.residual(model.world_params(x)), weight * x]

    x0 = np.zeros(model.size())
    result = fitting.fit(residuals, x0, 0.5, method="trf", xtol=1e-3, ftol=1e-4, max_nfev=40)
    fitted = model.world_params(result.x)
    report = {"frames": [f.episode for f in model.frames], "pixels": n_pixels,
              "residual_before": model.mean_abs_error(model.world_params(x0)),
              "residual_after": model.mean_abs_error(fitted), "evaluations": int(result.nfev)}
    return fitted, report


def calibrate_appearance(index: pd.DataFrame, frames_dir: str, estimates: pd.DataFrame, dataset: str, world: Mapping,
                         params: WorldParams, cfg: Mapping, camera: str) -> tuple[WorldParams, dict]:
    """``params`` (cameras, joints calibrated) with the fitted light and colours, and the fit's
    report; ``cfg``: ``calib.appearance``; ``camera``: the one the first frames are from."""
    params = dataclasses.replace(params, shadows=bool(cfg["shadows"]))
    if not cfg["fit"]:
        log.info("calib.appearance.fit is false: the calibrated sim keeps the model's light and colours")
        return params, {"fitted": False, "shadows": params.shadows}
    frames = appearance_frames(index, frames_dir, estimates, dataset, int(cfg["frames_per_task"]))
    model = AppearanceModel(frames, world, params, camera)
    try:
        fitted, report = fit_appearance(model, float(cfg["prior"]))
    finally:
        model.close()
    log.info("appearance: colour error %.1f -> %.1f (0-255) over %d pixels of %d first frames; light x%.3f, "
             "direction %+.3f %+.3f %+.3f, table %+.3f %+.3f %+.3f", report["residual_before"],
             report["residual_after"], report["pixels"], len(frames), fitted.light_intensity_scale,
             *fitted.light_dir_offset, *fitted.table_rgb_offset)
    return fitted, {"fitted": True, "shadows": fitted.shadows, **report}
