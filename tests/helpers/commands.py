"""Command sequences for the servo tests (the simulated servos' and the twin's)."""

from __future__ import annotations

import numpy as np

POSES = {"cup": (0.0, 0.1, 0.0), "plate": (-0.03, -0.08, 0.0)}  # the bundled cup_on_plate's objects


def wandering_commands(env, steps: int, seed: int) -> np.ndarray:
    """Joint targets and gripper commands wandering away from home (dataset layout)."""
    rng = np.random.default_rng(seed)
    start = env.robot.from_model(env.robot.home_targets())
    walk = start + np.cumsum(rng.normal(0.0, 0.02, (steps, start.size)), axis=0)
    _, grippers = zip(*(env.robot.slices(arm) for arm in env.robot.arms))
    walk[:, list(grippers)] = np.clip(walk[:, list(grippers)], 0.0, 1.0)
    return walk


def run(env, commands) -> tuple[np.ndarray, np.ndarray]:
    """The servo targets (``data.ctrl``) and joint positions after each command's control step."""
    env.reset(POSES, seed=0, observe=False)
    targets, joints = [], []
    for command in commands:
        env.step(command, images=False)
        targets.append(env.data.ctrl.copy())
        joints.append(env.data.qpos.copy())
    return np.stack(targets), np.stack(joints)
