"""Fixed cameras' poses from the robot's silhouette in the teleop recordings (no board needed).

The robot's joint states are recorded with every frame, so the simulation can draw the robot
where the frame shows it; only the camera's mount is unknown. The fit moves each fixed camera
(its mount error: three position and three rotation parameters, from the model's pose) until the
simulated silhouette lies over the recorded one in many frames at once.

- **The recorded silhouette** (in the frame undistorted through the camera's lens where one is
  known: ``lens_distortion``) is what the world says the robot looks like (``robot.find``: an
  HSV range, or the open-vocabulary segmenter's prompt), with the task objects' pixels (their own
  ``find``) left out of the comparison: an object in front of the arm is neither.
- **The simulated silhouette** is drawn by segmentation, so it depends on no colour or light: the
  robot's geoms, plus the scene geoms the same rule picks in the nominal rendering (a grey floor
  behind the table passes a grey robot's rule in both images), supersampled into a soft mask.
- **Frames**: from every episode, the ones that differ most in joint space (farthest-point
  sampling over the arms' joints), so the arm is seen in many poses: depth and lateral spread
  separate a camera's rotation from its translation.
- **The fit**: Gauss-Newton (scipy's least squares) on the difference of the two masks blurred by
  a Gaussian, coarse to fine (a wide blur first, so a camera centimetres off still sees the
  silhouettes overlap). A mismatch left above ``max_mismatch`` (share of the silhouettes' pixels
  that disagree) is an error that reports it and the worst frame. The fit's own curvature is no
  measure of its error here (neighbouring pixels' residuals are not independent, and a pixel of
  colour bleeding at the silhouette's edge biases every frame alike): how many frames of which
  poses pin a camera down is measured against the twin (``benchmarks/probe_silhouette_frames.py``).

A camera on an arm (a wrist camera) sees its own gripper from a fixed pose whatever the joints
do: its mount is not identifiable this way (calibrate it with a board take); it is skipped.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

import cv2
import mujoco
import numpy as np

from r2s_eval.calib import fitting
from r2s_eval.calib.cameras import camera_record, nominal_env
from r2s_eval.calib.scene import pinhole_coverage, pinhole_frame
from r2s_eval.calib.segment import HueRange, make_segmenter
from r2s_eval.data import STATE_KEY
from r2s_eval.data.contract import read_metadata
from r2s_eval.data.frames import episode_rows, read_frames
from r2s_eval.errors import ConfigError, DataError
from r2s_eval.sim import cameras as cam_geom
from r2s_eval.sim.render_params import mounted_pose
from r2s_eval.sim.tasks import world_tasks

log = logging.getLogger("r2s_eval.calib_silhouette")

POS_UNIT_M = 0.01  # the fit's parameters: centimetres and centiradians, so one step moves both alike
ROT_UNIT_RAD = 0.01
# A mount error is a calibration while it stays within 10 cm and 10 deg of the model's pose; the
# fit does not look beyond (a camera elsewhere is another camera: fix the world file).
BOUNDS = ([-10.0] * 3 + [-np.deg2rad(10.0) / ROT_UNIT_RAD] * 3, [10.0] * 3 + [np.deg2rad(10.0) / ROT_UNIT_RAD] * 3)


def pick_frames(states: Mapping[tuple[int, int], np.ndarray], n: int) -> list[tuple[int, int]]:
    """``n`` of the (episode, frame) keys whose states lie farthest apart (farthest-point
    sampling from the first), so the chosen frames show the robot in many poses."""
    keys = list(states)
    if len(keys) <= n:
        return keys
    points = np.stack([states[k] for k in keys])
    chosen = [0]
    dist = np.linalg.norm(points - points[0], axis=1)
    for _ in range(n - 1):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(points - points[nxt], axis=1))
    return [keys[i] for i in sorted(chosen)]


def strided_states(meta, episodes: Sequence[int], stride: int) -> dict[tuple[int, int], np.ndarray]:
    """The recorded state of every ``stride``-th frame of each of ``episodes`` (a dataset's
    metadata ``meta``), by (episode, frame index): the pool ``pick_frames`` picks from."""
    states = {}
    for episode in episodes:
        rows = episode_rows(meta, int(episode), [STATE_KEY])
        for i in range(0, len(rows), int(stride)):
            states[int(episode), int(rows["frame_index"][i])] = np.asarray(rows[STATE_KEY][i], float)
    return states


def robot_segmenter(robot, segmenter_cfg: Mapping):
    """``segment(image) -> mask`` of the robot as the world says it looks (``robot.find``)."""
    kind = segmenter_cfg.get("type", "hsv")
    if kind == "grounded_sam":
        from r2s_eval.calib.open_vocab import make_grounded_sam

        found = make_grounded_sam(segmenter_cfg, {"robot": robot.find_prompt or "a robot arm"})
        return lambda image: found.segment(image)["robot"]
    if robot.find_hue is None:
        raise ConfigError("world.robot.find.hue: the robot's colour range is needed to fit a camera to its "
                          "silhouette (calib.cameras.silhouette) with the hsv segmenter")
    rule = HueRange(**robot.find_hue)
    return lambda image: rule.mask(cv2.cvtColor(cv2.GaussianBlur(image, (5, 5), 0), cv2.COLOR_RGB2HSV))


class SilhouetteRenderer:
    """The simulation's robot silhouette from one camera, at given joint states, for any mount
    error of that camera: soft masks (supersampled), no colour or light involved."""

    def __init__(self, env, camera: str, states: Sequence[np.ndarray], size_hw: tuple[int, int], supersample: int,
                 robot_like: np.ndarray):
        self.env, self.model, self.camera = env, env.model, camera
        self.cam_id = env.model.camera(camera).id
        self.pos0, self.quat0 = env.model.cam_pos[self.cam_id].copy(), env.model.cam_quat[self.cam_id].copy()
        self.size_hw, self.k = size_hw, int(supersample)
        self.robot_like = robot_like  # per geom, then one entry for pixels no geom covers
        self.datas = []
        for state in states:  # one MjData per frame: posed once, only the camera moves after
            env.pose_robot(state)
            data = mujoco.MjData(env.model)
            data.qpos[:] = env.data.qpos
            mujoco.mj_forward(env.model, data)
            self.datas.append(data)
        h, w = size_hw
        self.renderer = env.renderer((h * self.k, w * self.k))

    def masks(self, dpos_m, drot_rad) -> np.ndarray:
        """(frames, H, W) soft silhouettes with the camera moved by a mount error."""
        pos, quat = mounted_pose(self.pos0, self.quat0, dpos_m, drot_rad)
        self.model.cam_pos[self.cam_id], self.model.cam_quat[self.cam_id] = pos, quat
        h, w = self.size_hw
        out = np.empty((len(self.datas), h, w), np.float32)
        self.renderer.enable_segmentation_rendering()
        try:
            for i, data in enumerate(self.datas):
                mujoco.mj_camlight(self.model, data)
                self.renderer.update_scene(data, camera=self.camera)
                seg = self.renderer.render()
                is_geom = (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (seg[..., 0] >= 0)
                hard = self.robot_like[np.where(is_geom, seg[..., 0], self.model.ngeom)]
                out[i] = hard.reshape(h, self.k, w, self.k).mean(axis=(1, 3))
        finally:
            self.renderer.disable_segmentation_rendering()
            self.model.cam_pos[self.cam_id], self.model.cam_quat[self.cam_id] = self.pos0, self.quat0
        return out


def robot_like_geoms(env, camera: str, states, size_hw, segment) -> np.ndarray:
    """Per geom, and last for the pixels no geom covers (the empty world beyond the scene),
    whether it counts as robot in the simulated silhouette: the robot's own geoms, and whatever
    else the robot's rule picks in most of its pixels of the nominal rendering (a grey floor, a
    black void)."""
    n = env.model.ngeom
    votes, seen = np.zeros(n + 1), np.zeros(n + 1)
    for state in states[:: max(1, len(states) // 4)]:
        env.pose_robot(state)
        rgb = env.render(camera, size=size_hw)
        seg = env.render_geoms(camera, size=size_hw)
        where = np.where(seg >= 0, seg, n)
        np.add.at(seen, where.ravel(), 1)
        np.add.at(votes, where.ravel(), segment(rgb).ravel())
    return np.r_[env.geom_is_robot, False] | ((seen > 0) & (votes > 0.5 * np.maximum(seen, 1)))


def fit_mount(renderer: SilhouetteRenderer, recorded: np.ndarray, valid: np.ndarray, blurs_px: Sequence[float]):
    """The mount error (dpos m, drot rad) that lays the simulated silhouettes over ``recorded``
    (frames, H, W in [0, 1]) on the ``valid`` pixels; coarse to fine over ``blurs_px``. Returns
    (dpos, drot, mismatch per frame)."""
    x = np.zeros(6)
    weights = valid.astype(np.float32)

    def blur(stack, sigma):
        return np.stack([cv2.GaussianBlur(m, (0, 0), sigma) for m in stack])

    for sigma in blurs_px:
        target = blur(recorded, sigma)

        def residuals(p, sigma=sigma, target=target):
            sim = blur(renderer.masks(p[:3] * POS_UNIT_M, p[3:] * ROT_UNIT_RAD), sigma)
            return ((sim - target) * weights).ravel()

        result = fitting.fit(residuals, x, 0.3, bounds=BOUNDS, method="trf", xtol=1e-4, ftol=1e-6, max_nfev=60)
        x = result.x
    final = renderer.masks(x[:3] * POS_UNIT_M, x[3:] * ROT_UNIT_RAD) > 0.5
    hard = recorded > 0.5
    mismatch = [float(np.sum((f ^ r) & v) / max(1, np.sum((f | r) & v))) for f, r, v in zip(final, hard, valid)]
    return x[:3] * POS_UNIT_M, x[3:] * ROT_UNIT_RAD, mismatch


def calibrate_from_silhouette(dataset: str, episodes: Sequence[int], world: Mapping, cfg: Mapping,
                              segmenter_cfg: Mapping, tasks: Sequence[str],
                              lens_distortion: Mapping[str, Sequence[float]] | None = None) -> dict:
    """Every recorded fixed camera's pose from the robot's silhouette in ``dataset``'s ``episodes``
    (``cfg``: ``calib.cameras.silhouette``; ``segmenter_cfg``: ``calib.segmenter``).
    ``lens_distortion``: the cameras' lenses where known (per camera, five coefficients, e.g. a
    board take's fit): the recorded frames are undistorted through them before their silhouettes
    are compared with the pinhole renders (``r2s_eval.calib.scene.pinhole_frame``); None: pinholes."""
    env = nominal_env(world, tasks, lens_distortion)
    robot = env.robot
    try:
        segment = robot_segmenter(robot, segmenter_cfg)
        objects = {o.name: o for t in world_tasks(world).values() for o in t.objects}
        find_objects = make_segmenter({"type": "hsv"}, {n: o.rgba for n, o in objects.items()},
                                      {n: {"hue": o.hue, "prompt": o.prompt} for n, o in objects.items()})
        for name in env.task.object_names:  # out of sight: only the robot is drawn
            env.set_object_pose(name, (0.0, 0.0, -5.0))
        meta = read_metadata(dataset)
        states = strided_states(meta, episodes, int(cfg["stride"]))
        chosen = pick_frames(states, int(cfg["frames"]))
        if len(chosen) < int(cfg["min_frames"]):
            raise DataError(f"dataset {dataset}: {len(chosen)} frames to fit the cameras' silhouettes, at least "
                            f"{cfg['min_frames']} needed (calib.cameras.silhouette.min_frames)")
        cameras = cam_geom.fixed_cameras(env.model, world["cameras"])
        skipped = {c: "moves with the arm: its own gripper's silhouette does not depend on its joints; use a board take"
                   for c in world["cameras"] if c not in cameras}
        images = read_frames(meta, chosen, cameras)
        chosen_states = [states[k] for k in chosen]
        out = {}
        for cam in cameras:
            size_hw = images[chosen[0] + (cam,)].shape[:2]
            # Undistorted through the camera's lens where known, as the pinhole renders see the scene.
            frames = [pinhole_frame(env, cam, images[k + (cam,)]) for k in chosen]
            recorded = np.stack([segment(f) for f in frames]).astype(np.float32)
            objects_seen = [np.any(list(find_objects.segment(f).values()), axis=0) for f in frames]
            valid = ~np.stack([cv2.dilate(m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0 for m in objects_seen])
            valid &= pinhole_coverage(env, cam, size_hw)  # a lens's corners the undistorted frame lacks
            robot_like = robot_like_geoms(env, cam, chosen_states, size_hw, segment)
            renderer = SilhouetteRenderer(env, cam, chosen_states, size_hw, int(cfg["supersample"]), robot_like)
            dpos, drot, mismatch = fit_mount(renderer, recorded, valid, [float(b) for b in cfg["blur_px"]])
            left = float(np.mean(mismatch))
            where = f"dataset {dataset}, camera {cam}"
            if left > float(cfg["max_mismatch"]):
                worst = int(np.argmax(mismatch))
                raise DataError(f"{where}: the silhouette fit did not converge: {100 * left:.1f} % of the silhouettes' "
                                f"pixels still disagree (limit {100 * float(cfg['max_mismatch']):.0f} %, "
                                f"calib.cameras.silhouette.max_mismatch); worst: episode {chosen[worst][0]} frame "
                                f"{chosen[worst][1]} ({100 * mismatch[worst]:.1f} %)")
            T = cam_geom.T_parent_from_cam(*mounted_pose(renderer.pos0, renderer.quat0, dpos, drot))
            out[cam] = {**camera_record(env, cam, T), "frames_used": [list(k) for k in chosen], "mismatch": left}
            log.info("%s: mount error %s mm, %s deg; the silhouettes disagree on %.1f %% of their pixels over %d "
                     "frames", cam, np.round(1000 * dpos, 1).tolist(), np.round(np.rad2deg(drot), 2).tolist(),
                     100 * left, len(chosen))
        for cam, why in skipped.items():
            log.info("%s: skipped: %s", cam, why)
    finally:
        env.close()
    return {"method": "silhouette", "dataset": str(dataset), "frames": len(chosen), "cameras": out,
            "skipped": skipped}
