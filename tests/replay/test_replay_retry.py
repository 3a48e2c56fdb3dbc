"""Automatic action replay: success from good estimates, bounded retries from bad ones."""

from __future__ import annotations

import numpy as np
import pytest

import r2s_eval  # noqa: F401
from r2s_eval.replay import perturb, replay_episode, retry_design
from r2s_eval.twin.operator import make_operator, run_episode
from tests.helpers.worlds import bundled_env


@pytest.fixture(scope="module")
def demo():
    env = bundled_env("cup_on_plate", cameras=("head_left",))
    poses = env.sample_initial_poses(np.random.default_rng(2))
    obs = env.reset(poses, seed=0)
    steps = run_episode(env, make_operator("cup_on_plate", env, np.random.default_rng(0)), 150, obs)
    assert env.is_success()
    yield env, poses, np.stack([a for _, a in steps])
    env.close()


def test_replay_from_true_poses_succeeds_first_time(demo):
    env, poses, actions = demo
    result = replay_episode(env, actions, poses, np.random.default_rng(0), max_attempts=8, perturb_xy_m=0.01,
                            perturb_yaw_rad=0.1)
    assert result.success and result.attempts == 1
    assert len(result.frames) == len(actions)
    obs, action = result.frames[0]
    assert obs["observation.images.head_left"].shape == (128, 128, 3)
    np.testing.assert_array_equal(action, actions[0])


def test_replay_gives_up_after_max_attempts(demo):
    env, poses, actions = demo
    x, y, yaw = poses["cup"]
    wrong = dict(poses, cup=(x + 0.08, y, yaw))  # 8 cm off: +-1 cm retries cannot reach it
    result = replay_episode(env, actions, wrong, np.random.default_rng(0), max_attempts=3, perturb_xy_m=0.01,
                            perturb_yaw_rad=np.pi)
    assert not result.success and result.attempts == 3


def test_perturbation_bounds():
    design = retry_design(200, 1, np.random.default_rng(0))
    base = {"cup": (0.1, -0.05, 0.3)}
    for offsets in design:
        x, y, yaw = perturb(base, offsets, 0.01, np.pi)["cup"]
        assert abs(x - 0.1) <= 0.01 and abs(y + 0.05) <= 0.01 and abs(yaw - 0.3) <= np.pi
    # Observable yaw stays within +-yaw_rad; a rotationally symmetric object's yaw is redrawn.
    design = retry_design(200, 2, np.random.default_rng(1))
    yaws = [perturb({"block": (0, 0, 0.3), "ball": (0, 0, 0.3)}, offsets, 0.01, 0.1, {"block": 4, "ball": 0})
            for offsets in design]
    assert all(abs(p["block"][2] - 0.3) <= 0.1 for p in yaws)
    assert max(abs(p["ball"][2] - 0.3) for p in yaws) > 1.0


def test_eight_retries_cover_every_eighth_of_each_axis():
    for seed in range(20):
        design = retry_design(8, 2, np.random.default_rng(seed))
        assert design.shape == (8, 2, 3) and np.all(np.abs(design) <= 1)
        # Each of the six axes (x, y, yaw of both objects) has one retry per eighth of its range.
        bins = np.floor((design.reshape(8, 6) + 1) / 2 * 8).astype(int)
        assert all(sorted(bins[:, axis]) == list(range(8)) for axis in range(6)), seed
    # Seeded per episode: the same generator state gives the same retries.
    np.testing.assert_array_equal(retry_design(8, 2, np.random.default_rng(3)), retry_design(8, 2, np.random.default_rng(3)))
    assert retry_design(5, 1, np.random.default_rng(0)).shape == (5, 1, 3)
    assert retry_design(0, 1, np.random.default_rng(0)).shape == (0, 1, 3)
