"""The robot's joint offsets, estimated from its own recordings (no ground truth used).

A real arm does not hold a joint exactly where it was told: a servo's zero is off, a
proportional controller sags under load. Recorded joint actions replayed in a simulation that
lacks those offsets put the gripper millimetres to centimetres away from where it was, and a
policy trained on the robot's data (its states and actions carry the offsets) commands the
wrong poses in that simulation, and the other way round.

The estimate is the replay's residual: replay an episode's recorded actions open loop in the
simulation (objects at their estimated initial poses), and compare the recorded joint positions
with the simulated ones, frame by frame. Per joint, the median residual over every frame of
every episode is the offset the simulation lacks. The offsets change the arm's pose, hence its
contacts and load, so the fit is repeated with the offsets applied (a fixed point: each pass
adds the median residual that is left).

What this cannot see: an encoder's zero error moves the reading and the servo together, so the
recorded state and action agree and only the images show the arm elsewhere. That needs the
robot's silhouette in the camera frames; it is not estimated here.

The commands' latency (``estimate_latency``): a robot's command reaches its servos some control
steps after it was recorded (camera, bus, processing). The servos themselves lag their targets
too, so the lag between the recorded commands and the measured joints is not the latency; the
lag between the measured joints and the same commands replayed in the simulation (which has the
servos' own lag, not the latency) is. The replay is the offsets' first one (no offsets, no
latency); for each lag tried, the replayed joints are delayed by it (held at their start before
it, as a delayed robot holds its reset targets) and compared with the recorded ones by their
velocities (which the offsets do not move), over every arm joint that moves. The lag of the
least residual is the latency the calibrated sim is built with, and the offsets' passes replay
with it.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from tqdm import tqdm

from r2s_eval.data import ACTION_KEY, STATE_KEY, episode_frames, open_metadata
from r2s_eval.errors import DataError
from r2s_eval.sim import TabletopEnv, WorldParams
from r2s_eval.sim.build import make_env as world_env
from r2s_eval.sim.robot import Robot, world_robot

log = logging.getLogger("r2s_eval.calib_joints")

Poses = dict[str, tuple[float, float, float]]
# A joint whose recorded commands or measured angles span less than this in an episode shows no
# lag (a few encoder steps, well above the reading noise).
MIN_MOTION_RAD = float(np.deg2rad(1.0))


@dataclass(frozen=True)
class RecordedEpisode:
    """What the fit needs of one recorded episode: its task, its objects' estimated initial
    poses, and its recorded states and actions (dataset layout and units, ``(T, D)``)."""

    episode_index: int
    task: str
    poses: Poses
    states: np.ndarray
    actions: np.ndarray


@dataclass(frozen=True)
class JointFit:
    """Per arm, the estimated joint offsets (rad, in the arm's joint order); the median residual
    each pass found (the first pass: the nominal simulation's; the last: what is left); and the
    frames they rest on."""

    offsets_rad: dict[str, tuple[float, ...]]
    pass_residual_rad: list[dict[str, tuple[float, ...]]]
    episodes: int
    frames: int


@dataclass(frozen=True)
class LatencyFit:
    """The commands' latency (whole control steps): the lag of the least residual among
    ``lags_steps``; per lag, the RMS of the recorded minus the delayed replay's joint velocities
    (rad per control step); the moving joint series (episode, arm joint) and frames it rests on."""

    steps: int
    lags_steps: tuple[int, ...]
    rms_velocity_residual_rad: tuple[float, ...]
    moving_joints: int
    frames: int


def recorded_episodes(dataset: str, index: pd.DataFrame, estimates: pd.DataFrame) -> list[RecordedEpisode]:
    """The episodes of ``index`` (ingest's) read from ``dataset``, their objects where
    ``estimates`` (init_estimate's) put them."""
    meta = open_metadata(dataset)
    episodes = []
    for ep in tqdm(index.itertuples(), total=len(index), desc="calib_joints read", mininterval=5):
        est = estimates[estimates["episode_index"] == ep.episode_index]
        if est.empty:
            raise DataError(f"episode {ep.episode_index}: no initial-pose estimate")
        frames = episode_frames(dataset, meta, ep.episode_index)
        episodes.append(RecordedEpisode(
            episode_index=int(ep.episode_index), task=ep.task,
            poses={r.object: (r.x_m, r.y_m, r.yaw_rad) for r in est.itertuples()},
            states=np.stack(frames[STATE_KEY].to_numpy()).astype(float),
            actions=np.stack(frames[ACTION_KEY].to_numpy()).astype(float)))
    return episodes


def replay_residuals(env: TabletopEnv, episode: RecordedEpisode) -> dict[str, np.ndarray]:
    """Per arm, recorded minus simulated joint positions (model units, ``(T, n_joints)``), with
    the episode's actions replayed open loop from its poses."""
    recorded = recorded_joints(env.robot, episode)
    return {arm: recorded[arm] - simulated for arm, simulated in replayed_joints(env, episode).items()}


def recorded_joints(robot: Robot, episode: RecordedEpisode, key: str = "states") -> dict[str, np.ndarray]:
    """Per arm, the episode's recorded joint positions (``key="actions"``: its commanded ones),
    model units, ``(T, n_joints)``."""
    _check_width(robot, episode)
    per_frame = [robot.to_model(v) for v in getattr(episode, key)]
    return {arm: np.stack([f[arm][0] for f in per_frame]) for arm in robot.arms}


def replayed_joints(env: TabletopEnv, episode: RecordedEpisode) -> dict[str, np.ndarray]:
    """Per arm, the simulated joint positions before each of the episode's actions, replayed open
    loop from its poses (model units, ``(T, n_joints)``)."""
    robot = env.robot
    _check_width(robot, episode)
    env.reset(episode.poses, seed=episode.episode_index)
    simulated = []
    for action in episode.actions:
        simulated.append(env.state())
        env.step(action, images=False)
    per_frame = [robot.to_model(s) for s in simulated]
    return {arm: np.stack([f[arm][0] for f in per_frame]) for arm in robot.arms}


def _check_width(robot: Robot, episode: RecordedEpisode) -> None:
    if episode.actions.shape != episode.states.shape or episode.actions.shape[1:] != (robot.action_dim,):
        raise DataError(f"episode {episode.episode_index}: states {episode.states.shape} and actions "
                        f"{episode.actions.shape} do not both have the robot's {robot.action_dim} entries per frame")


def replay_all(episodes: Sequence[RecordedEpisode], make_env: Callable[[str, WorldParams], TabletopEnv],
               params: WorldParams) -> list[dict[str, np.ndarray]]:
    """``replayed_joints`` of every episode in its task's simulation under ``params``."""
    envs: dict[str, TabletopEnv] = {}
    try:
        replayed = []
        for episode in episodes:
            if episode.task not in envs:
                envs[episode.task] = make_env(episode.task, params)
            replayed.append(replayed_joints(envs[episode.task], episode))
        return replayed
    finally:
        for env in envs.values():
            env.close()


def nominal_replay_params(robot: Robot) -> WorldParams:
    """The offsets' first pass's simulation (no offsets, no latency), whose replay the latency
    estimate reads too."""
    return WorldParams(joint_offset_rad={arm: (0.0,) * len(spec.joints) for arm, spec in robot.arms.items()})


def estimate_latency(robot: Robot, episodes: Sequence[RecordedEpisode], replayed: Sequence[dict[str, np.ndarray]],
                     max_lag_steps: int, source: str) -> LatencyFit:
    """The commands' latency in whole control steps, 0 to ``max_lag_steps`` (module docstring):
    ``replayed``, per episode, its joints replayed with neither offsets nor latency
    (``replayed_joints``); ``source`` names the recordings in errors."""
    if max_lag_steps < 0:
        raise DataError(f"calib.joints.max_latency_steps must be >= 0, got {max_lag_steps}")
    if not episodes:
        raise DataError(f"{source}: no recorded episodes to estimate the commands' latency from")
    lags = tuple(range(int(max_lag_steps) + 1))
    squares, counts, moving = np.zeros(len(lags)), np.zeros(len(lags)), 0
    for episode, simulated in zip(episodes, replayed, strict=True):
        recorded, commanded = recorded_joints(robot, episode), recorded_joints(robot, episode, "actions")
        frames = np.arange(len(episode.states))
        for arm, sim in simulated.items():
            moves = ((np.ptp(commanded[arm], axis=0) > MIN_MOTION_RAD)
                     & (np.ptp(recorded[arm], axis=0) > MIN_MOTION_RAD))
            if len(frames) < 2 or not moves.any():
                continue
            moving += int(moves.sum())
            measured = np.diff(recorded[arm][:, moves], axis=0)
            for i, lag in enumerate(lags):
                # Delayed by `lag`: held at its start until the first command arrives.
                delayed = np.diff(sim[np.maximum(frames - lag, 0)][:, moves], axis=0)
                squares[i] += float(np.sum((measured - delayed) ** 2))
                counts[i] += measured.size
    if moving == 0:
        raise DataError(f"{source}: no arm joint moves by {np.rad2deg(MIN_MOTION_RAD):g} deg in both its recorded "
                        f"commands and its measured angles in any of {len(episodes)} episodes, so there is no lag "
                        f"between command and joint to read (set calib.joints.latency: false)")
    rms = np.sqrt(squares / counts)
    return LatencyFit(steps=lags[int(np.argmin(rms))], lags_steps=lags,
                      rms_velocity_residual_rad=tuple(float(v) for v in rms), moving_joints=moving,
                      frames=int(sum(len(e.actions) for e in episodes)))


def estimate_joint_offsets(robot: Robot, episodes: Sequence[RecordedEpisode],
                           make_env: Callable[[str, WorldParams], TabletopEnv], iterations: int,
                           latency_steps: int = 0,
                           nominal_replay: Sequence[dict[str, np.ndarray]] | None = None) -> JointFit:
    """The offsets that make the simulation's joints follow the recorded ones (module docstring).

    ``make_env(task, params)``: the task's simulation under ``params`` (no cameras needed);
    ``iterations``: passes of the fixed point (2 is enough where the load barely moves with the
    offsets); ``latency_steps``: the commands' latency every pass replays with;
    ``nominal_replay``: the episodes already replayed under ``nominal_replay_params`` (the latency
    estimate's), which the first pass reuses when there is no latency."""
    if iterations < 1:
        raise DataError(f"calib.joints.iterations must be >= 1, got {iterations}")
    if not episodes:
        raise DataError("no recorded episodes to estimate the joint offsets from")
    offsets = {arm: np.zeros(len(spec.joints)) for arm, spec in robot.arms.items()}
    recorded = [recorded_joints(robot, e) for e in episodes]
    passes = []
    for i in range(iterations):
        params = WorldParams(joint_offset_rad=_as_tuples(offsets), command_latency_steps=int(latency_steps))
        if i == 0 and latency_steps == 0 and nominal_replay is not None:
            replayed = nominal_replay  # the same simulation, replayed already
        else:
            replayed = replay_all(episodes, make_env, params)
        step = {arm: np.median(np.concatenate([r[arm] - s[arm] for r, s in zip(recorded, replayed, strict=True)]),
                               axis=0)
                for arm in offsets}
        passes.append(_as_tuples(step))
        offsets = {arm: offsets[arm] + step[arm] for arm in offsets}
    return JointFit(offsets_rad=_as_tuples(offsets), pass_residual_rad=passes, episodes=len(episodes),
                    frames=int(sum(len(e.actions) for e in episodes)))


def fit_summary(fit: JointFit) -> list[str]:
    """One log line per arm: its offsets and the median residual its last pass found. The arm's
    name starts the line and no other word on it names a side (a bimanual robot's arms are
    called left and right)."""
    return [f"arm {arm}: joint offsets (deg) {np.round(np.rad2deg(offsets), 2).tolist()}; "
            f"median residual after the last pass (deg) "
            f"{np.round(np.rad2deg(fit.pass_residual_rad[-1][arm]), 3).tolist()}"
            for arm, offsets in fit.offsets_rad.items()]


def _as_tuples(per_arm: dict[str, Iterable[float]]) -> dict[str, tuple[float, ...]]:
    return {arm: tuple(float(v) for v in values) for arm, values in per_arm.items()}


def calibrate_joints(dataset: str, index: pd.DataFrame, estimates: pd.DataFrame, world: dict, *, estimate: bool,
                     iterations: int, latency: bool = False, max_latency_steps: int = 3) -> dict:
    """The calibrated sim's world parameters and how they were found, as the ``calib_joints``
    stage writes them: ``{"params": WorldParams as a dict, "joints": {"estimated": bool, ...}}``.

    With ``estimate`` the joint offsets are fitted on every recorded episode of ``index`` (objects
    at their ``estimates``) in the ``world`` config's simulation; with ``latency`` the commands'
    latency is estimated from the same episodes (lags 0 to ``max_latency_steps``), the calibrated
    sim delays its commands by it and the offsets' passes replay with it (``joints.latency_steps``,
    and per lag tried its residual in ``joints.latency``). Without either, the parameters are nominal.
    """
    robot = world_robot(world)
    report: dict = {"estimated": bool(estimate)}
    if not (estimate or latency):
        log.info("calib.joints.estimate and calib.joints.latency are false: the calibrated sim keeps the nominal "
                 "joints and servos")
        return {"params": dataclasses.asdict(WorldParams()), "joints": report}
    episodes = recorded_episodes(dataset, index, estimates)

    def make_env(task: str, params: WorldParams) -> TabletopEnv:
        return world_env(task, world, params, cameras=[])

    latency_steps, nominal_replay = 0, None
    if latency:
        nominal_replay = replay_all(episodes, make_env, nominal_replay_params(robot))
        lag = estimate_latency(robot, episodes, nominal_replay, int(max_latency_steps), source=str(dataset))
        latency_steps = lag.steps
        rms_deg = [float(np.rad2deg(v)) for v in lag.rms_velocity_residual_rad]
        report.update(latency_steps=lag.steps, latency={
            "lags_steps": list(lag.lags_steps), "rms_velocity_residual_deg_per_step": rms_deg,
            "moving_joints": lag.moving_joints, "frames": lag.frames})
        log.info("commands' latency: %d control steps (RMS joint velocity residual per lag %s: %s deg per step)",
                 lag.steps, list(lag.lags_steps), np.round(rms_deg, 4).tolist())
    offsets: dict[str, tuple[float, ...]] = {}
    if estimate:
        fit = estimate_joint_offsets(robot, episodes, make_env, int(iterations), latency_steps, nominal_replay)
        offsets = fit.offsets_rad
        report.update(episodes=fit.episodes, frames=fit.frames, offsets_rad=fit.offsets_rad,
                      pass_residual_rad=fit.pass_residual_rad)
        for line in fit_summary(fit):
            log.info("%s", line)
    else:
        log.info("calib.joints.estimate is false: the calibrated sim keeps the nominal joints")
    params = WorldParams(joint_offset_rad=offsets, command_latency_steps=latency_steps)
    return {"params": dataclasses.asdict(params), "joints": report}
