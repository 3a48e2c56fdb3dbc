"""The calibrated sim's camera poses: from a board take (``calibrate_from_board``), read back as
world parameters (``camera_params``), and scored against a known truth (``camera_errors``).

An estimate is stored as each camera's mount error against the model's nominal pose, in the
camera's own frame (``WorldParams.camera_pos_offset_m`` / ``camera_rot_offset_rad``): what the
twin perturbs, and what replay, rollouts and the initial-pose estimate build their cameras with.
The robot-silhouette estimate (``r2s_eval.calib.silhouette``) writes the same record.

With ``calib.cameras.board.intrinsics`` the board take also gives each camera's lens
(``r2s_eval.calib.board.fit_lens``): its distortion goes into the calibrated sim
(``WorldParams.lens_distortion``, applied through the sim's own K); its fitted focal lengths and
principal point are reported against the model's K, which the sim keeps (MuJoCo's ``fovy`` is
one number for both axes and its principal point the image's centre; a lab whose camera differs
writes the fitted intrinsics into its world's camera, ``intrinsics``).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping, Sequence

import numpy as np

from r2s_eval.calib import poses
from r2s_eval.calib.board import (Board, CameraFit, Lens, board_on_table, find_board, fit_camera, fit_lens, lens_pixels,
                                  views_of_stated_board)
from r2s_eval.calib.take import read_take
from r2s_eval.errors import ConfigError
from r2s_eval.sim import TabletopEnv, WorldParams, world_params_from_record
from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.assembly import ee_site
from r2s_eval.sim.build import make_env
from r2s_eval.sim.render_params import key_light, mounted_pose
from r2s_eval.sim.robot import world_robot
from r2s_eval.utils.io import read_json

log = logging.getLogger("r2s_eval.calib_cameras")


def nominal_env(world: Mapping, tasks: Sequence[str],
                lens_distortion: Mapping[str, Sequence[float]] | None = None) -> TabletopEnv:
    """The calibrated sim before its cameras are calibrated (the first task's scene, objects
    aside): its kinematics and its cameras' nominal mounts; ``lens_distortion``: the lenses
    already fitted (per camera, five coefficients), which its cameras record through."""
    return make_env(tasks[0], world, WorldParams(lens_distortion=dict(lens_distortion or {})), cameras=())


def body_pose(env: TabletopEnv, body: int) -> np.ndarray:
    return poses.pose(env.data.xmat[body].reshape(3, 3), env.data.xpos[body])


def camera_record(env: TabletopEnv, camera: str, T_parent_from_cam: np.ndarray) -> dict:
    """The mount error that puts ``camera`` at ``T_parent_from_cam`` (OpenCV frame, parent body)."""
    cid = env.model.camera(camera).id
    dpos, drot = cam_geom.mount_error(env.model.cam_pos[cid], env.model.cam_quat[cid], T_parent_from_cam)
    return {"pos_offset_m": [float(v) for v in dpos], "rot_offset_rad": [float(v) for v in drot]}


def calibrate_from_board(take_path: str, world: Mapping, board_cfg: Mapping, tasks: Sequence[str]) -> dict:
    """Every recorded camera's pose from the board take at ``take_path`` (``r2s_eval.calib.take``);
    ``board_cfg``: ``calib.cameras.board``. A camera whose frames show too little of the board is
    an error naming the frames left out and why. With ``intrinsics``, each camera's lens first (a
    take too sparse to fit it is an error naming the camera and what is missing), the poses then
    found through it."""
    robot = world_robot(world)
    board = Board.from_config(board_cfg)
    cameras = list(world["cameras"])
    take = read_take(take_path, cameras, robot.feature_names)
    env = nominal_env(world, tasks)
    min_corners, min_frames = int(board_cfg["min_corners"]), int(board_cfg["min_frames"])
    mount = board_cfg["mount"]
    try:
        if mount != "table" and mount not in robot.arms:
            raise ConfigError(f"calib.cameras.board.mount: 'table' or an arm of the robot {list(robot.arms)}, "
                              f"got {mount!r}")
        holder = None if mount == "table" else int(env.model.site_bodyid[env.model.site(ee_site(mount)).id])
        parents = {cam: int(env.model.cam_bodyid[env.model.camera(cam).id]) for cam in cameras}
        world_poses: dict[int, dict[int, np.ndarray]] = {}  # frame -> body -> T_world_from_body
        for frame, state in enumerate(take.states):
            env.pose_robot(state)
            world_poses[frame] = {b: body_pose(env, b) for b in {*parents.values(), holder or 0}}
        pose = board_cfg["pose"]
        stated = (board_on_table(board, float(pose["x_m"]), float(pose["y_m"]), float(pose["yaw_rad"]),
                                 robot.workspace_z_m) if mount == "table" else None)
        out = {}
        for cam in cameras:
            images = take.images[cam]
            K = env.camera_K(cam, images[0].shape[:2])
            where = f"board take {take_path}, camera {cam}"
            views, left_out = [], {}
            for frame, image in enumerate(images):
                found = find_board(image, board, K, frame, min_corners)
                if isinstance(found, str):
                    left_out[frame] = found
                else:
                    views.append(found)
            lens = None
            if board_cfg["intrinsics"]:
                lens = fit_lens(views, K, images[0].shape[:2], board,
                                max_rms_px=float(board_cfg["max_reprojection_px"]), where=where, left_out=left_out)
                left_out.update(lens.left_out)
                views = lens.views
                log.info("%s: lens from %d views, %d corners: fx %.2f fy %.2f cx %.2f cy %.2f px (model: f %.2f, "
                         "%.2f, %.2f), distortion %s; reprojection %.3f px (%.3f px without distortion)", cam,
                         len(lens.views), lens.corners, lens.K[0, 0], lens.K[1, 1], lens.K[0, 2], lens.K[1, 2],
                         K[1, 1], K[0, 2], K[1, 2], np.round(lens.distortion, 4).tolist(), lens.rms_px,
                         lens.pinhole_rms_px)
            parent_poses = {f: world_poses[f][parents[cam]] for f in world_poses}
            holder_poses = {f: world_poses[f][holder or 0] for f in world_poses}
            if lens is not None and stated is not None:
                # A lens take may carry the board through the view: those views fit the lens only.
                views, moved = views_of_stated_board(views, parent_poses,
                                                     {f: T @ stated for f, T in holder_poses.items()})
                left_out.update(moved)
                if moved:
                    log.info("%s: %d frames show the board away from its stated pose: the lens only", cam, len(moved))
            fitted = functools.partial(fit_camera, views, K if lens is None else lens.K, board, parent_poses,
                                       holder_poses, stated, min_frames=min_frames,
                                       max_rms_px=float(board_cfg["max_reprojection_px"]), where=where,
                                       left_out=left_out, distortion=None if lens is None else lens.distortion)
            # A board on the table: every camera takes its stated pose (as the fixed ones must). A
            # camera on an arm also finds where the board lies (slid and turned on the table from
            # the statement), which says how far off the statement is. A carried board: found.
            fit = fitted("free" if stated is None else "fixed")
            found = fitted("planar") if stated is not None and env.model.body_weldid[parents[cam]] != 0 else None
            out[cam] = {**camera_record(env, cam, fit.T_parent_from_cam), **_fit_record(fit, stated, found)}
            if lens is not None:
                out[cam]["intrinsics"] = _lens_record(lens, K)
            log.info("%s: %d frames, reprojection %.2f px, standard error %.2f mm / %.3f deg; %d frames left out",
                     cam, len(fit.frames_used), fit.rms_px, fit.std_position_mm, fit.std_rotation_deg,
                     len(fit.frames_left_out))
            for frame, why in sorted(fit.frames_left_out.items()):
                log.info("%s: frame %d left out: %s", cam, frame, why)
    finally:
        env.close()
    return {"method": "board", "take": str(take_path), "frames": len(take.states), "cameras": out}


def _fit_record(fit: CameraFit, stated: np.ndarray | None, found: CameraFit | None) -> dict:
    record = {"frames_used": fit.frames_used,
              "frames_left_out": {str(f): why for f, why in sorted(fit.frames_left_out.items())},
              "reprojection_px": fit.rms_px, "std_position_mm": fit.std_position_mm,
              "std_rotation_deg": fit.std_rotation_deg}
    if found is not None:  # the board's pose the views give against the lab's statement
        mm, deg = poses.distance(found.T_mount_from_board, stated)
        record["board_from_stated"] = {"mm": mm, "deg": deg}
    return record


def _intrinsics(K: np.ndarray) -> dict[str, float]:
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}


def _lens_record(lens: Lens, K_model: np.ndarray) -> dict:
    """A camera's fitted lens for the record: the intrinsics at the take's image size against the
    model's (which the calibrated sim keeps), the distortion (which it takes), the reprojection
    error (RMS over the corners, each view at its own pose) with the distortion terms and without
    them (a pinhole K refitted to the same corners), and what the fit used."""
    fitted, model = _intrinsics(lens.K), _intrinsics(K_model)
    return {"image_size": list(lens.image_size), "fitted": fitted, "model": model,
            "focal_from_model_pct": {a: 100.0 * (fitted[a] / model[a] - 1.0) for a in ("fx", "fy")},
            "principal_point_from_model_px": [fitted["cx"] - model["cx"], fitted["cy"] - model["cy"]],
            "distortion": [float(v) for v in lens.distortion],
            "reprojection_px": {"with_distortion": lens.rms_px, "without_distortion": lens.pinhole_rms_px},
            "views": len(lens.views), "corners": lens.corners, "cells_covered": lens.cells_covered,
            "tilts": lens.tilts}


def camera_params(record: Mapping | None) -> dict:
    """``WorldParams`` fields of a cameras record (``{"cameras": {cam: {pos_offset_m, ...}}}``):
    the cameras' mount errors and, where the record fitted it, each lens's distortion; None: the
    nominal cameras."""
    cams = (record or {}).get("cameras") or {}
    return {"camera_pos_offset_m": {c: tuple(v["pos_offset_m"]) for c, v in cams.items()},
            "camera_rot_offset_rad": {c: tuple(v["rot_offset_rad"]) for c, v in cams.items()},
            "lens_distortion": {c: tuple(v["intrinsics"]["distortion"]) for c, v in cams.items() if "intrinsics" in v}}


def calibrated_cameras(path: str | None) -> WorldParams:
    """World parameters holding the cameras of a cameras record file (None: the model's)."""
    return WorldParams(**camera_params(read_json(path) if path else None))


def camera_errors(estimated: WorldParams, truth: WorldParams, world: Mapping, tasks: Sequence[str],
                  cameras: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per camera, how far the estimated pose is from the true one: position (mm) and angle (deg),
    in the camera's parent frame (a wrist camera: on its link)."""
    env = nominal_env(world, tasks)
    try:
        out = {}
        for cam in cameras:
            cid = env.model.camera(cam).id
            placed = [cam_geom.T_parent_from_cam(*mounted_pose(
                env.model.cam_pos[cid], env.model.cam_quat[cid], params.camera_pos_offset_m.get(cam, (0.0, 0.0, 0.0)),
                params.camera_rot_offset_rad.get(cam, (0.0, 0.0, 0.0)))) for params in (estimated, truth)]
            mm, deg = poses.distance(*placed)
            out[cam] = {"position_mm": mm, "rotation_deg": deg}
        return out
    finally:
        env.close()


def key_light_error_deg(estimated: WorldParams, truth: WorldParams, world: Mapping, tasks: Sequence[str]) -> float:
    """The angle (deg) between the key light's direction (``r2s_eval.sim.render_params.key_light``)
    in the world of ``estimated`` and in the world of ``truth`` (their ``light_dir_offset``)."""
    env = nominal_env(world, tasks)
    try:
        base = env.model.light_dir.copy()
        key = key_light(env.model.light_diffuse)
    finally:
        env.close()
    if key is None:
        return float("nan")
    directions = [base[key] + np.asarray(p.light_dir_offset, float) for p in (estimated, truth)]
    a, b = (d / np.linalg.norm(d) for d in directions)
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


LENS_GRID_POINTS = (64, 48)  # pixels the lens errors are averaged over: a grid spanning the image


def lens_errors(record: Mapping, true_lenses: Mapping[str, Sequence[float]], world: Mapping,
                tasks: Sequence[str]) -> dict[str, dict]:
    """Per camera whose lens a cameras record fitted, against the twin's true lens
    (``true_lenses[camera]``: the reality record's ``lens_distortion``, OpenCV's rational model's
    eight coefficients, through the model's K, as the twin records; a camera missing is a
    pinhole), at the take's image size: how far the calibrated sim's lens (the fitted five
    coefficients through the model's K, which the sim keeps) puts a ray from where the twin's puts
    it (``distortion_px``: RMS over a grid of rays spanning the image, ``distortion_max_px``: the
    largest), what a sim without a lens leaves (``model_px``), and the fitted focal lengths (%) and
    principal point (px) against the twin's."""
    env = nominal_env(world, tasks)
    try:
        out = {}
        for cam, fit in record["cameras"].items():
            lens = fit.get("intrinsics")
            if not lens:
                continue
            height, width = lens["image_size"]
            K = env.camera_K(cam, (height, width))
            u, v = np.meshgrid(np.linspace(0.0, width - 1.0, LENS_GRID_POINTS[0]),
                               np.linspace(0.0, height - 1.0, LENS_GRID_POINTS[1]))
            rays = (np.c_[u.ravel(), v.ravel(), np.ones(u.size)] @ np.linalg.inv(K).T)[:, :2]
            true = lens_pixels(rays, K, true_lenses.get(cam) or (0.0,) * 5)
            off = np.linalg.norm(lens_pixels(rays, K, lens["distortion"]) - true, axis=1)
            fitted = lens["fitted"]
            out[cam] = {"distortion_px": float(np.sqrt(np.mean(off**2))), "distortion_max_px": float(off.max()),
                        "model_px": float(np.sqrt(np.mean(np.sum((np.c_[u.ravel(), v.ravel()] - true) ** 2, axis=1)))),
                        "focal_pct": {"fx": float(100.0 * (fitted["fx"] / K[0, 0] - 1.0)),
                                      "fy": float(100.0 * (fitted["fy"] / K[1, 1] - 1.0))},
                        "principal_point_px": float(np.hypot(fitted["cx"] - K[0, 2], fitted["cy"] - K[1, 2])),
                        "image_size": [int(height), int(width)]}
        return out
    finally:
        env.close()


def look_errors(sim: WorldParams, truth: WorldParams) -> dict:
    """The fitted light's intensity beside the twin's (``light_scale``: {"sim", "twin"}) and each
    object's colour off the twin's (``object_rgb_error``: {object: {"sim", "model"}}, the mean
    absolute difference of its colour offset, 0-255; ``model``: the world file's colour)."""
    def error(offset, true_offset):
        return float(255.0 * np.mean(np.abs(np.subtract(offset, true_offset))))

    return {"light_scale": {"sim": float(sim.light_intensity_scale), "twin": float(truth.light_intensity_scale)},
            "object_rgb_error": {name: {"sim": error(sim.object_rgb_offset.get(name, (0.0, 0.0, 0.0)), true),
                                        "model": error((0.0, 0.0, 0.0), true)}
                                 for name, true in sorted(truth.object_rgb_offset.items())}}


def score_calibration(estimates: Mapping[str, dict], calibrated: Mapping, truth: WorldParams, world: Mapping,
                      tasks: Sequence[str], true_lenses: Mapping[str, Sequence[float]] | None = None,
                      true_shadows: bool | None = None) -> dict:
    """Each camera estimate (``{method: cameras record}``) and the model's own poses against the
    twin's true cameras (``truth``: its world parameters), which estimate the calibrated sim
    (``calibrated``: its world parameters file) used, and its appearance fit's colour error before
    and after (with background plates, each plated camera's first-frame colour error with its plate
    and without, ``background``); with an estimate that fitted the cameras' lenses, each lens against the twin's true
    one (``true_lenses``: its reality record's ``lens_distortion``; None: pinholes) (``lens``:
    ``lens_errors``); with ``true_shadows`` (the twin's reality record: whether its key light casts
    them), the sim's shadows beside it and the angle between the two key lights (``appearance``:
    ``shadows``, ``twin_shadows``, ``key_light_deg``); a fitted appearance, its light and colours
    against the twin's (``look_errors``)."""
    cameras = sorted({c for record in estimates.values() for c in record["cameras"]}) or list(world["cameras"])
    scored = {"model": camera_errors(WorldParams(), truth, world, tasks, cameras)}
    for method, record in estimates.items():
        scored[method] = camera_errors(WorldParams(**camera_params(record)), truth, world, tasks, list(record["cameras"]))
    appearance = calibrated.get("appearance") or {}
    report = {"cameras": scored, "used": (calibrated.get("cameras") or {}).get("method", "none"),
              "appearance": {k: appearance.get(k) for k in ("fitted", "residual_before", "residual_after")}}
    sim = world_params_from_record(calibrated.get("params") or {})
    if appearance.get("fitted"):
        report["appearance"].update(look_errors(sim, truth))
    if true_shadows is not None:  # the twin's shadows, and the key light that casts them, against the sim's
        report["appearance"].update(shadows=sim.shadows, twin_shadows=bool(true_shadows),
                                    key_light_deg=key_light_error_deg(sim, truth, world, tasks))
    lenses = {method: lens_errors(record, true_lenses or {}, world, tasks) for method, record in estimates.items()
              if any("intrinsics" in fit for fit in record["cameras"].values())}
    if lenses:  # only where a lens was fitted: without one the report is what it was
        report["lens"] = lenses
    plates = (calibrated.get("background") or {}).get("errors")
    if plates:  # the background plates' first-frame colour errors (r2s_eval.calib.background.plate_errors)
        report["background"] = plates
    return report

