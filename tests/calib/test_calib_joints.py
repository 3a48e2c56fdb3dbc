"""The joint offsets are recovered from recorded states and actions alone."""

from __future__ import annotations

import numpy as np
import pytest

from r2s_eval.calib.joints import JointFit, RecordedEpisode, estimate_joint_offsets, fit_summary, replay_residuals
from r2s_eval.errors import DataError
from r2s_eval.sim import TabletopEnv, WorldParams
from tests.helpers.worlds import bundled_env

TASK = "cup_on_plate"
POSES = {"cup": (0.05, 0.02, 0.0), "plate": (-0.08, -0.03, 0.0)}


def make_env(task: str, params: WorldParams) -> TabletopEnv:
    return bundled_env(task, params=params, cameras=())


def record(params: WorldParams, seed: int, steps: int = 40) -> RecordedEpisode:
    """Joint targets wandering around home, recorded in a world built with ``params``."""
    env = make_env(TASK, params)
    rng = np.random.default_rng(seed)
    env.reset(POSES, seed=seed)
    start = env.state().astype(float)
    actions = start + np.cumsum(rng.normal(0.0, 0.01, (steps, start.size)), axis=0)
    states = []
    for action in actions:
        states.append(env.state().astype(float))
        env.step(action, images=False)
    env.close()
    return RecordedEpisode(seed, TASK, POSES, np.stack(states), actions)


def test_offsets_of_a_world_are_recovered_from_its_recordings():
    robot = make_env(TASK, WorldParams()).robot
    rng = np.random.default_rng(0)
    truth = {arm: tuple(rng.uniform(-0.03, 0.03, len(spec.joints))) for arm, spec in robot.arms.items()}
    episodes = [record(WorldParams(joint_offset_rad=truth), seed) for seed in range(3)]
    fit = estimate_joint_offsets(robot, episodes, make_env, iterations=2)
    for arm, offsets in truth.items():
        assert np.abs(np.subtract(fit.offsets_rad[arm], offsets)).max() < 2e-3, arm
        # The first pass sees the whole offset; the last one what little is left.
        assert np.abs(fit.pass_residual_rad[-1][arm]).max() < 2e-3
    assert fit.episodes == 3 and fit.frames == 120


def test_a_nominal_recording_gives_no_offsets():
    robot = make_env(TASK, WorldParams()).robot
    fit = estimate_joint_offsets(robot, [record(WorldParams(), 7)], make_env, iterations=1)
    for offsets in fit.offsets_rad.values():
        assert np.abs(offsets).max() < 1e-6


def test_each_arms_log_line_names_that_arm_alone():
    # A bimanual robot's arms are left and right: the right arm's line once said "residual left".
    fit = JointFit(offsets_rad={"left": (np.deg2rad(1.0), 0.0), "right": (np.deg2rad(-2.0), np.deg2rad(0.5))},
                   pass_residual_rad=[{"left": (0.1, 0.1), "right": (0.1, 0.1)},
                                      {"left": (0.0, np.deg2rad(0.01)), "right": (np.deg2rad(0.02), 0.0)}],
                   episodes=1, frames=10)
    left, right = fit_summary(fit)
    assert left == "arm left: joint offsets (deg) [1.0, 0.0]; median residual after the last pass (deg) [0.0, 0.01]"
    assert right == "arm right: joint offsets (deg) [-2.0, 0.5]; median residual after the last pass (deg) [0.02, 0.0]"
    assert "left" not in right


def test_an_episode_of_the_wrong_width_is_named():
    episode = record(WorldParams(), 1)
    bad = RecordedEpisode(41, TASK, POSES, episode.states[:, :-1], episode.actions[:, :-1])
    env = make_env(TASK, WorldParams())
    with pytest.raises(DataError, match="episode 41"):
        replay_residuals(env, bad)


def test_no_episodes_or_no_pass_is_refused():
    robot = make_env(TASK, WorldParams()).robot
    with pytest.raises(DataError, match="no recorded episodes"):
        estimate_joint_offsets(robot, [], make_env, iterations=1)
    with pytest.raises(DataError, match="iterations"):
        estimate_joint_offsets(robot, [record(WorldParams(), 2)], make_env, iterations=0)


def test_calibrate_joints_writes_the_fitted_params_or_the_nominal_ones(monkeypatch):
    import dataclasses
    from pathlib import Path

    from r2s_eval.calib import joints
    from r2s_eval.config import compose_config

    world = compose_config(Path(__file__).resolve().parents[2] / "conf", "smoke")["world"]
    nominal = joints.calibrate_joints("data", None, None, world, estimate=False, iterations=2)
    assert nominal == {"params": dataclasses.asdict(WorldParams()), "joints": {"estimated": False}}

    robot = make_env(TASK, WorldParams()).robot
    truth = {arm: tuple(0.02 for _ in spec.joints) for arm, spec in robot.arms.items()}
    monkeypatch.setattr(joints, "recorded_episodes", lambda dataset, index, estimates: [record(WorldParams(joint_offset_rad=truth), 0)])
    fitted = joints.calibrate_joints("data", None, None, world, estimate=True, iterations=2)
    report = fitted["joints"]
    assert report["estimated"] and report["episodes"] == 1 and report["frames"] == 40 and len(report["pass_residual_rad"]) == 2
    for arm, offsets in truth.items():
        assert np.abs(np.subtract(fitted["params"]["joint_offset_rad"][arm], offsets)).max() < 2e-3
