"""Closed-loop episode recording: trajectory contract, success handling, video round trip."""

from __future__ import annotations

import numpy as np
import pytest

import r2s_eval  # noqa: F401
from r2s_eval.rollout import episode_id, read_video, run_episode, write_video
from r2s_eval.sim import TabletopEnv
from r2s_eval.sim.teleop import make_operator


class OperatorPolicy:
    """The scripted operator behind the policy interface (a policy that knows the task)."""

    def __init__(self, env):
        self.env, self.op = env, None

    def reset(self):
        self.op = None

    def act(self, obs):
        if self.op is None:
            self.op = make_operator("cup_on_plate", self.env, np.random.default_rng(0))
        action = self.op.act(obs)
        return action


class FrozenPolicy:
    def __init__(self):
        self.action = None

    def reset(self):
        self.action = None

    def act(self, obs):
        if self.action is None:
            self.action = np.asarray(obs["observation.state"], dtype=float).copy()
        return self.action


@pytest.fixture(scope="module")
def env():
    env = TabletopEnv("cup_on_plate", cameras=("head_left",))
    yield env
    env.close()


def test_successful_episode_stops_and_records(env):
    poses = env.sample_initial_poses(np.random.default_rng(4))
    policy = OperatorPolicy(env)
    policy.reset()
    result = run_episode(env, policy, poses, seed=1, max_steps=150, video_camera="head_left")
    assert result.success and result.length < 150
    traj = result.trajectory
    assert len(traj) == result.length and len(result.frames) == result.length + 1
    for column in ("step", "time_s", "state", "action", "ee_pos_left", "ee_pos_right", "contact_force_n",
                   "progress", "obj_pos.cup", "obj_quat.plate"):
        assert column in traj.columns
    assert len(traj["state"][0]) == 14 and len(traj["obj_quat.plate"][0]) == 4
    assert traj["progress"].iloc[-1] == pytest.approx(1.0)
    assert traj["success"].iloc[-3:].all()


def test_policy_that_never_moves_fails_at_max_steps(env):
    poses = env.sample_initial_poses(np.random.default_rng(4))
    policy = FrozenPolicy()
    policy.reset()
    result = run_episode(env, policy, poses, seed=1, max_steps=20, video_camera="head_left")
    assert not result.success and result.length == 20
    assert result.trajectory["progress"].max() < 0.5


def test_video_round_trip(tmp_path):
    frames = [np.full((64, 48, 3), 10 * i, np.uint8) for i in range(12)]
    path = tmp_path / "v.mp4"
    write_video(path, frames, fps=10)
    decoded = read_video(path)
    assert decoded.shape == (12, 64, 48, 3)
    assert abs(float(decoded[5].mean()) - 50.0) < 3.0
    assert not list(tmp_path.glob(".*.tmp"))


def test_episode_ids_are_opaque_and_stable():
    a = episode_id("sim", "act", "cup_on_plate", 3, 11)
    assert a == episode_id("sim", "act", "cup_on_plate", 3, 11)
    assert a != episode_id("sim", "diffusion", "cup_on_plate", 3, 11)
    assert "act" not in a and len(a) == 16
