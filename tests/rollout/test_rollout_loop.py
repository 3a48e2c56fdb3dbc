"""Closed-loop episode recording: trajectory contract, success handling, video round trip."""

from __future__ import annotations

import numpy as np
import pytest

import r2s_eval  # noqa: F401
from r2s_eval.rollout import episode_id, read_video, run_episode, video_frame_every, write_video

from tests.helpers.policies import FrozenPolicy, OperatorPolicy
from tests.helpers.worlds import bundled_env


@pytest.fixture(scope="module")
def env():
    env = bundled_env("cup_on_plate", cameras=("head_left",))
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


class ScriptedPolicy:
    """Deterministic, and reads its camera image: any change in what it sees changes its actions."""

    def __init__(self, camera="head_left"):
        self.key, self.t = f"observation.images.{camera}", 0

    def reset(self):
        self.t = 0

    def act(self, obs):
        self.t += 1
        action = np.asarray(obs["observation.state"], dtype=float).copy()
        image_term = float(np.asarray(obs[self.key], dtype=float).mean()) / 255.0
        action[0] += 0.02 * np.sin(0.3 * self.t) + 1e-3 * image_term
        action[7] -= 0.02 * np.sin(0.3 * self.t)
        return action


def _noisy_env(cameras):
    from r2s_eval.sim import WorldParams

    return bundled_env("cup_on_plate", params=WorldParams(image_noise_std=4.0), cameras=cameras)


@pytest.mark.parametrize("cameras", [("head_left",), ("head_right",)])
def test_judge_video_size_leaves_the_policy_inputs_unchanged(cameras):
    # Watching the video camera or not: the judge render must not touch the observations'
    # images, their noise stream, or the trajectory.
    env = _noisy_env(cameras)
    try:
        poses = env.sample_initial_poses(np.random.default_rng(4))
        results, seen = {}, {}
        for size in (None, (448, 448)):
            policy = ScriptedPolicy(cameras[0])
            images = []
            act = policy.act
            policy.act = lambda obs, act=act: (images.append(obs[policy.key].copy()), act(obs))[1]
            policy.reset()
            results[size] = run_episode(env, policy, poses, seed=3, max_steps=8, video_camera="head_left",
                                        video_size=size)
            seen[size] = np.stack(images)
        a, b = results[None], results[(448, 448)]
        assert np.array_equal(seen[None], seen[(448, 448)])
        for column in ("action", "state", "obj_pos.cup", "ee_pos_left"):
            assert np.array_equal(np.stack(a.trajectory[column]), np.stack(b.trajectory[column])), column
        assert a.frames[0].shape == (128, 128, 3) and b.frames[0].shape == (448, 448, 3)
        assert len(a.frames) == len(b.frames) == 9
    finally:
        env.close()


def test_judge_video_is_configured_size_and_shows_the_robot(env, tmp_path):
    poses = env.sample_initial_poses(np.random.default_rng(4))
    policy = ScriptedPolicy()
    policy.reset()
    result = run_episode(env, policy, poses, seed=1, max_steps=10, video_camera="head_left", video_size=(448, 448))
    path = tmp_path / "judge.mp4"
    write_video(path, result.frames, fps=10)
    video = read_video(path)
    assert video.shape == (11, 448, 448, 3)
    assert abs(float(video[-1].mean()) - float(result.frames[-1].mean())) < 3.0
    # The robot is in view at the judge camera and size: both arms, a real share of the frame.
    labels, names = env.render("head_left", size=(448, 448), segmentation=True)
    ids = {n: k for k, n in names.items()}
    robot = np.isin(labels, (ids["robot_left"], ids["robot_right"]))
    assert robot.mean() > 0.02
    assert (labels == ids["robot_left"]).any() and (labels == ids["robot_right"]).any()
    assert (labels == ids["cup"]).any() and (labels == ids["plate"]).any()


def test_video_larger_than_the_default_offscreen_buffer(env):
    image = env.render("head_left", size=(720, 960))
    assert image.shape == (720, 960, 3) and image.std() > 1.0


def test_judge_video_keeps_every_kth_control_step(env):
    # 5 fps at 10 Hz control: steps 0, 2, 4, ...; the frames are those of a video at every step.
    assert video_frame_every(5, 0.1) == 2 and video_frame_every(10, 0.1) == 1
    with pytest.raises(ValueError, match="must divide the control rate"):
        video_frame_every(3, 0.1)
    poses = env.sample_initial_poses(np.random.default_rng(4))
    runs = {}
    for every in (1, 2):
        policy = ScriptedPolicy()
        policy.reset()
        runs[every] = run_episode(env, policy, poses, seed=1, max_steps=9, video_camera="head_left",
                                  video_size=(64, 64), frame_every=every)
    assert len(runs[1].frames) == 10 and len(runs[2].frames) == 5
    for k, frame in enumerate(runs[2].frames):
        assert np.array_equal(frame, runs[1].frames[2 * k])
    assert runs[1].trajectory.equals(runs[2].trajectory)


def test_images_are_the_same_whether_or_not_the_steps_before_were_rendered():
    # The noise of a camera at a step is keyed by the step: a loop that renders only at query
    # steps shows the policy the very pixels a loop rendering every step does.
    envs = [_noisy_env(("head_left", "wrist_right")) for _ in range(2)]
    try:
        poses = envs[0].sample_initial_poses(np.random.default_rng(2))
        for e in envs:
            e.reset(poses, seed=5)
        action = envs[0].state().astype(float)
        for step in range(1, 7):
            every = envs[0].step(action)
            lazy = envs[1].step(action, images=False)
            assert set(lazy) == {"observation.state"}
            if step % 3 == 0:
                lazy.update(envs[1].images())
                for key, image in every.items():
                    assert np.array_equal(image, lazy[key]), (step, key)
        assert not np.array_equal(every["observation.images.head_left"], envs[0].render("head_left"))  # noisy
    finally:
        for e in envs:
            e.close()
