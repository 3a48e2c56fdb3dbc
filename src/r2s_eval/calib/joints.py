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
    robot = env.robot
    if episode.actions.shape != episode.states.shape or episode.actions.shape[1:] != (robot.action_dim,):
        raise DataError(f"episode {episode.episode_index}: states {episode.states.shape} and actions "
                        f"{episode.actions.shape} do not both have the robot's {robot.action_dim} entries per frame")
    env.reset(episode.poses, seed=episode.episode_index)
    simulated = []
    for action in episode.actions:
        simulated.append(env.state())
        env.step(action, images=False)
    recorded = [robot.to_model(s) for s in episode.states]
    simulated = [robot.to_model(s) for s in simulated]
    return {arm: np.stack([r[arm][0] for r in recorded]) - np.stack([s[arm][0] for s in simulated])
            for arm in robot.arms}


def estimate_joint_offsets(robot: Robot, episodes: Sequence[RecordedEpisode],
                           make_env: Callable[[str, WorldParams], TabletopEnv], iterations: int) -> JointFit:
    """The offsets that make the simulation's joints follow the recorded ones (module docstring).

    ``make_env(task, params)``: the task's simulation under ``params`` (no cameras needed);
    ``iterations``: passes of the fixed point (2 is enough where the load barely moves with the
    offsets)."""
    if iterations < 1:
        raise DataError(f"calib.joints.iterations must be >= 1, got {iterations}")
    if not episodes:
        raise DataError("no recorded episodes to estimate the joint offsets from")
    offsets = {arm: np.zeros(len(spec.joints)) for arm, spec in robot.arms.items()}
    passes = []
    for _ in range(iterations):
        params = WorldParams(joint_offset_rad=_as_tuples(offsets))
        envs: dict[str, TabletopEnv] = {}
        residuals: dict[str, list[np.ndarray]] = {arm: [] for arm in offsets}
        try:
            for episode in episodes:
                if episode.task not in envs:
                    envs[episode.task] = make_env(episode.task, params)
                for arm, r in replay_residuals(envs[episode.task], episode).items():
                    residuals[arm].append(r)
        finally:
            for env in envs.values():
                env.close()
        step = {arm: np.median(np.concatenate(r), axis=0) for arm, r in residuals.items()}
        passes.append(_as_tuples(step))
        offsets = {arm: offsets[arm] + step[arm] for arm in offsets}
    return JointFit(offsets_rad=_as_tuples(offsets), pass_residual_rad=passes, episodes=len(episodes),
                    frames=int(sum(len(e.actions) for e in episodes)))


def _as_tuples(per_arm: dict[str, Iterable[float]]) -> dict[str, tuple[float, ...]]:
    return {arm: tuple(float(v) for v in values) for arm, values in per_arm.items()}


def calibrate_joints(dataset: str, index: pd.DataFrame, estimates: pd.DataFrame, world: dict, *, estimate: bool,
                     iterations: int) -> dict:
    """The calibrated sim's world parameters and how they were found, as the ``calib_joints``
    stage writes them: ``{"params": WorldParams as a dict, "joints": {"estimated": bool, ...}}``.

    With ``estimate`` the joint offsets are fitted on every recorded episode of ``index`` (objects
    at their ``estimates``) in the ``world`` config's simulation; without, the parameters are nominal.
    """
    robot = world_robot(world)
    report: dict = {"estimated": bool(estimate)}
    params = WorldParams()
    if estimate:
        fit = estimate_joint_offsets(robot, recorded_episodes(dataset, index, estimates),
                                     lambda task, p: world_env(task, world, p, cameras=[]), int(iterations))
        params = WorldParams(joint_offset_rad=fit.offsets_rad)
        report.update(episodes=fit.episodes, frames=fit.frames, offsets_rad=fit.offsets_rad,
                      pass_residual_rad=fit.pass_residual_rad)
        for arm, offsets in fit.offsets_rad.items():
            log.info("%s joint offsets (deg): %s; residual left (deg): %s", arm,
                     np.round(np.rad2deg(offsets), 2).tolist(),
                     np.round(np.rad2deg(fit.pass_residual_rad[-1][arm]), 3).tolist())
    else:
        log.info("calib.joints.estimate is false: the calibrated sim keeps the nominal joints")
    return {"params": dataclasses.asdict(params), "joints": report}
