"""The room behind the robot as each fixed camera recorded it: a background plate per camera, which
the calibrated sim draws its robot and task objects over (SimplerEnv's visual matching: the real
background behind the simulator's foreground mask, arXiv 2405.05941).

No world file holds a lab's room (its table's grain, its walls, the things standing about), and a
policy trained on real frames sees that room in every image. So the plate is taken from the
recordings themselves:

- **Frames**: every ``stride``-th frame of every episode, of which the ``frames`` whose arm poses
  differ most (farthest-point sampling over the joints, as the silhouette fit picks them): the arm
  in many places uncovers as much of the room as the recordings ever show.
- **What is not room**: the robot where the calibrated sim draws it at the frame's recorded joints
  (its calibrated camera, through its lens), and the task objects where the initial-pose estimate
  put them at the episode's start (many stay there: a plate a cup is put on), both widened by
  ``margin_px`` (the recording smears colour across an edge). Where an object goes mid-episode
  is known to no one, and its colour rule is no help in a furnished room (a red cup's rule fires
  on a wooden table's grain): a moved object, the arm's shadow and anything else that moves are
  left to the median.
- **The plate**: per pixel, the median over the frames in which it is room. An object that stands
  on a pixel in fewer than half of those frames (objects start elsewhere in each episode and move)
  does not reach the plate. A pixel seen free in fewer than ``min_free_frames`` frames is filled
  from its neighbours (OpenCV's inpainting). When more than ``max_unseen`` of the pixels the moving
  arm can uncover are never free of the robot itself, the recordings never show that part of the
  room and the camera is refused (the robot's bases, and an arm that rests throughout while another
  works, do not count: the sim draws them where they are); pixels that an object's start pose always covers (a plate
  whose start region is smaller than the plate) are only inpainted: the sim draws its object there.

A camera on an arm sees the room move past it with every joint: no plate holds it, and the
calibrated sim keeps drawing its own table and the world beyond for such a camera.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from r2s_eval.calib.silhouette import pick_frames, strided_states
from r2s_eval.data import STATE_KEY
from r2s_eval.data.contract import read_metadata
from r2s_eval.data.frames import episode_rows, read_frames
from r2s_eval.errors import DataError
from r2s_eval.sim import WorldParams
from r2s_eval.sim.build import make_env
from r2s_eval.sim.cameras import fixed_cameras

log = logging.getLogger("r2s_eval.calib_background")

WRIST_CAMERA = "moves with its arm: the room slides past it with every joint, so no plate holds it; the " \
               "calibrated sim draws its own table and surroundings for it"


def foreground_masks(envs: Mapping, camera: str, frames: Sequence[tuple[str, Mapping | None, np.ndarray]],
                     size_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Two (frames, H, W) bool stacks: where the calibrated sim draws the robot, and where it draws
    the task objects at their initial poses, in each of ``frames`` (task, its episode's initial
    object poses or None, the recorded state), as the camera records it (through the world's lens
    of that camera)."""
    robot, objects = (np.empty((len(frames), *size_hw), bool) for _ in range(2))
    for i, (task, poses, state) in enumerate(frames):
        env = envs[task]
        if poses is None:  # no estimate: the objects out of sight, the robot alone
            env.reset(settle=False, observe=False)
            for name in env.task.object_names:
                env.set_object_pose(name, (0.0, 0.0, -5.0))
        else:
            env.reset(poses, settle=False, observe=False)
        env.pose_robot(state)
        geoms = env.render_geoms(camera, size_hw)
        is_robot = (geoms >= 0) & env.geom_is_robot[np.clip(geoms, 0, None)]
        drawn = env.foreground_mask(camera, size_hw, geoms)
        robot[i] = env.lens_image(is_robot.astype(np.uint8) * 255, camera) > 127
        objects[i] = env.lens_image((drawn & ~is_robot).astype(np.uint8) * 255, camera) > 127
    return robot, objects


RESTING_RAD = 0.02  # an arm whose joints span less than this over the recordings never left its pose


def resting_arms(env, states: Sequence[np.ndarray]) -> list[str]:
    """The arms whose joints stay put (within ``RESTING_RAD``) over the recorded ``states`` while
    another arm moves: an arm no task of the recordings used, which a policy trained on them keeps
    where it is. None where no arm moves (recordings of a robot at rest show no room behind it)."""
    joints = [env.robot.to_model(state) for state in states]
    resting = [arm for arm in env.robot.arms
               if np.ptp(np.stack([np.asarray(j[arm][0], float) for j in joints]), axis=0).max() < RESTING_RAD]
    return [] if len(resting) == len(env.robot.arms) else resting


def static_robot_mask(env, camera: str, size_hw: tuple[int, int], states: Sequence[np.ndarray]) -> np.ndarray:
    """Where the robot's parts that never move cover the camera's view, posed at the first of the
    recorded ``states``: its bases, and every arm that rests throughout the recordings
    (``resting_arms``). No recording shows the room behind them, and the sim draws them there."""
    m = env.model
    fixed_geom = env.geom_is_robot & (m.body_weldid[m.geom_bodyid] == 0)
    env.pose_robot(states[0])
    geoms = env.render_geoms(camera, size_hw)
    labels, names = env.render(camera, size_hw, segmentation=True)
    resting = [label for label, name in names.items() if name in {f"robot_{a}" for a in resting_arms(env, states)}]
    static = (fixed_geom[np.clip(geoms, 0, None)] & (geoms >= 0)) | np.isin(labels, resting)
    return env.lens_image(static.astype(np.uint8) * 255, camera) > 127


def plate_from_frames(frames: np.ndarray, occupied: np.ndarray, min_free_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The per-pixel median of ``frames`` (N, H, W, 3 uint8) over the frames where the pixel is not
    ``occupied`` (N, H, W bool), with the pixels free in fewer than ``min_free_frames`` frames
    inpainted from their neighbours. Returns (plate uint8[H, W, 3], free count int[H, W])."""
    free = ~occupied
    counts = free.sum(axis=0)
    values = np.where(free[..., None], frames.astype(np.float32), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN pixel: never free, inpainted below
        median = np.nanmedian(values, axis=0)
    unseen = counts < int(min_free_frames)
    plate = np.nan_to_num(median, nan=0.0).round().clip(0, 255).astype(np.uint8)
    if unseen.any():
        plate = cv2.inpaint(plate, unseen.astype(np.uint8), 3, cv2.INPAINT_TELEA)
    return plate, counts


def fit_plates(dataset: str, index, estimates, world: Mapping, params: WorldParams,
               cfg: Mapping) -> tuple[dict[str, np.ndarray], dict]:
    """A plate per recorded fixed camera of ``dataset``'s episodes in ``index`` (ingest's: episode
    and task), seen through the calibrated sim of ``params`` (its cameras and lens); the objects
    where ``estimates`` (the initial-pose estimates, or None) put them at each episode's start are
    not room either (many stay there: a plate a cup is put on). ``cfg``: ``calib.background``.
    Returns ({camera: RGB plate}, the record: per camera the frames used, the free frames per pixel
    and the share of the room never seen; the cameras skipped and why; ``states``, the robot's
    recorded state at each frame used, from which the sim takes the same median of its own room
    and so knows which of its shadows the plates hold, ``WorldParams.background_states``, and
    ``margin_px``, how far around the robot a frame did not count, ``background_margin_px``)."""
    task_of = {int(e): str(t) for e, t in zip(index["episode_index"], index["task"])}
    poses_of = {} if estimates is None else {
        int(e): {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in rows.itertuples()}
        for e, rows in estimates.groupby("episode_index")}
    envs = {task: make_env(task, world, params, cameras=()) for task in sorted(set(task_of.values()))}
    try:
        meta = read_metadata(dataset)
        states = strided_states(meta, task_of, int(cfg["stride"]))
        chosen = pick_frames(states, int(cfg["frames"]))
        env = next(iter(envs.values()))
        recorded = [c for c in world["cameras"] if f"observation.images.{c}" in meta.features]
        cameras = fixed_cameras(env.model, recorded)
        skipped = {c: WRIST_CAMERA for c in recorded if c not in cameras}
        images = read_frames(meta, chosen, cameras)
        margin = np.ones((2 * int(cfg["margin_px"]) + 1,) * 2, np.uint8)
        scenes = [(task_of[e], poses_of.get(e), states[e, f]) for e, f in chosen]
        plates, out = {}, {}
        for cam in cameras:
            frames = np.stack([images[k + (cam,)] for k in chosen])
            size_hw = frames.shape[1:3]
            robot, objects = (np.stack([cv2.dilate(m.astype(np.uint8), margin) > 0 for m in stack])
                              for stack in foreground_masks(envs, cam, scenes, size_hw))
            plate, counts = plate_from_frames(frames, robot | objects, int(cfg["min_free_frames"]))
            needed = ~static_robot_mask(env, cam, size_hw, [states[k] for k in chosen])
            least = int(cfg["min_free_frames"])
            # Only the robot can hide the room for good: a pixel the objects' start poses always
            # cover (a plate in every episode's start region) is drawn over by the sim's object too.
            unseen = ((~robot).sum(axis=0) < least) & needed
            share = float(unseen.sum() / max(1, needed.sum()))
            inpainted = float(((counts < least) & needed).sum() / max(1, needed.sum()))
            if share > float(cfg["max_unseen"]):
                raise DataError(
                    f"dataset {dataset}, camera {cam}: {100 * share:.1f} % of the room behind the moving arm is "
                    f"never seen free of the robot in {len(chosen)} frames of {len(task_of)} episodes (fewer "
                    f"than {cfg['min_free_frames']} free frames; limit {100 * float(cfg['max_unseen']):g} %, "
                    "calib.background.max_unseen): record some frames with the arm moved out of the view, or set "
                    "calib.background.fit: false")
            plates[cam] = plate
            out[cam] = {"frames_used": [list(k) for k in chosen], "image_size": list(size_hw),
                        "free_frames_median": float(np.median(counts[needed])),
                        "free_frames_min": int(counts[needed].min()), "unseen_share": share,
                        "inpainted_share": inpainted}
            log.info("%s: plate from %d frames; a pixel of the room is free in %d of them (median); %.2f %% never "
                     "free of the robot, %.2f %% inpainted (the objects' start poses too)", cam, len(chosen),
                     out[cam]["free_frames_median"], 100 * share, 100 * inpainted)
        for cam, why in skipped.items():
            log.info("%s: no plate: %s", cam, why)
    finally:
        for env in envs.values():
            env.close()
    return plates, {"dataset": str(dataset), "frames": len(chosen), "cameras": out, "skipped": skipped,
                    "objects_masked": estimates is not None, "margin_px": int(cfg["margin_px"]),
                    "states": [np.asarray(states[k], float).tolist() for k in chosen] if plates else []}


def write_plates(plates: Mapping[str, np.ndarray], folder: str | Path) -> dict[str, str]:
    """Each camera's plate as ``<folder>/<camera>.png``; returns {camera: path}."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for cam, plate in plates.items():
        path = folder / f"{cam}.png"
        if not cv2.imwrite(str(path), cv2.cvtColor(plate, cv2.COLOR_RGB2BGR)):
            raise DataError(f"cannot write the background plate of camera {cam} to {path}")
        paths[cam] = str(path)
    return paths


def plate_errors(dataset: str, index, estimates, world: Mapping, params: WorldParams, appearance_cfg: Mapping) -> dict:
    """How far the calibrated sim's first frames lie from the recorded ones, with its plates and
    without (its own surroundings): per plated camera, the mean absolute colour error (0-255, every
    pixel) over the first frames of the episodes the appearance fit reads (``appearance_cfg``:
    ``calib.appearance``, its ``frames_per_task`` of each task), the sim at each episode's
    estimated object poses (``estimates``) and recorded first state. The plates were taken from
    the same recordings: an in-sample figure of how much of the image the room makes up."""
    meta = read_metadata(dataset)
    per_task = int(appearance_cfg["frames_per_task"])
    chosen = [int(e) for _, rows in index.groupby("task", sort=True) for e in rows.head(per_task)["episode_index"]]
    cameras = sorted(params.background_plates)
    if not cameras or not chosen:
        return {}
    images = read_frames(meta, [(e, 0) for e in chosen], cameras)
    task_of = dict(zip(index["episode_index"].astype(int), index["task"]))
    without = dataclasses.replace(params, background_plates={})
    errors = {cam: {"with_plate": [], "without_plate": []} for cam in cameras}
    envs = {}
    try:
        for episode in chosen:
            task = task_of[episode]
            if task not in envs:
                envs[task] = (make_env(task, world, params, cameras=()), make_env(task, world, without, cameras=()))
            rows = estimates[estimates["episode_index"] == episode]
            poses = {r.object: (r.x_m, r.y_m, r.yaw_rad) for r in rows.itertuples()}
            state = np.asarray(episode_rows(meta, episode, [STATE_KEY])[STATE_KEY][0], float)
            for key, env in zip(("with_plate", "without_plate"), envs[task]):
                env.reset(poses, settle=False, observe=False)
                env.pose_robot(state)
                for cam in cameras:
                    real = images[episode, 0, cam]
                    sim = env.render(cam, size=real.shape[:2], add_noise=True)
                    errors[cam][key].append(float(np.mean(np.abs(sim.astype(np.float32) - real))))
    finally:
        for pair in envs.values():
            for env in pair:
                env.close()
    return {cam: {key: float(np.mean(v)) for key, v in e.items()} | {"frames": len(chosen)} for cam, e in errors.items()}


SHADED = 0.85  # a room pixel the sim darkens below this share of its plate is in the sim's shadow
SHADOW_FRAMES = (0.25, 0.5, 0.75)  # where in each episode the shadows are compared (share of its frames)


def shadow_agreement(dataset: str, index, estimates, world: Mapping, params: WorldParams, appearance_cfg: Mapping) -> dict:
    """Whether the recordings are dark where the calibrated sim (with ``params.shadows``) casts its
    shadows over a plate: per plated camera, over the frames at ``SHADOW_FRAMES`` of the episodes the
    appearance fit reads, the sim posed at each frame's recorded joints (the objects where the
    estimate put them at the start: one that has moved since counts as room, a little noise), the
    room's pixels split by the sim's shade (``TabletopEnv.shadow_shade``, below ``SHADED``: in its
    shadow). Returns {camera: {"pixels": shaded pixels, "recorded": the recorded frames' brightness
    over the plate's there, "sim": the sim's shade there, "unshaded_recorded": the recorded over the
    plate's where the sim casts none, "frames"}}; {} without shadows or plates."""
    cameras = sorted(params.background_plates)
    if not params.shadows or not cameras:
        return {}
    meta = read_metadata(dataset)
    per_task = int(appearance_cfg["frames_per_task"])
    chosen = [int(e) for _, rows in index.groupby("task", sort=True) for e in rows.head(per_task)["episode_index"]]
    task_of = dict(zip(index["episode_index"].astype(int), index["task"]))
    sums = {cam: np.zeros(5) for cam in cameras}  # recorded, plate, shade where shaded; recorded, plate elsewhere
    counts = {cam: 0 for cam in cameras}
    frames, envs = [], {}
    try:
        for episode in chosen:
            states = np.stack(episode_rows(meta, episode, [STATE_KEY])[STATE_KEY].to_numpy()).astype(float)
            frames += [(episode, int(share * (len(states) - 1)), states[int(share * (len(states) - 1))])
                       for share in SHADOW_FRAMES]
        images = read_frames(meta, [(e, f) for e, f, _ in frames], cameras)
        for episode, frame, state in frames:
            task = task_of[episode]
            env = envs.get(task) or envs.setdefault(task, make_env(task, world, params, cameras=()))
            rows = estimates[estimates["episode_index"] == episode]
            env.reset({r.object: (r.x_m, r.y_m, r.yaw_rad) for r in rows.itertuples()}, settle=False, observe=False)
            env.pose_robot(state)
            for cam in cameras:
                real = images[episode, frame, cam].astype(np.float32).mean(axis=-1)
                size_hw = real.shape[:2]
                drawn = env.foreground_mask(cam, size_hw)
                shade = env.shadow_shade(cam, size_hw, env.render(cam, size=size_hw), drawn)
                shade = env.lens_image(shade, cam).astype(np.float32).mean(axis=-1) / 255.0
                room = env.lens_image((~drawn).astype(np.uint8) * 255, cam) > 254
                plate = env.background_plate(cam, size_hw).mean(axis=-1)
                shaded, lit = room & (shade < SHADED), room & (shade >= SHADED)
                sums[cam] += (real[shaded].sum(), plate[shaded].sum(), shade[shaded].sum(), real[lit].sum(),
                              plate[lit].sum())
                counts[cam] += int(shaded.sum())
    finally:
        for env in envs.values():
            env.close()
    out = {}
    for cam in cameras:
        recorded, plate, shade, lit_recorded, lit_plate = sums[cam]
        n = counts[cam]
        out[cam] = {"pixels": n, "recorded": float(recorded / plate) if n else None, "sim": float(shade / n) if n else None,
                    "unshaded_recorded": float(lit_recorded / max(lit_plate, 1.0)), "frames": len(frames)}
    return out
