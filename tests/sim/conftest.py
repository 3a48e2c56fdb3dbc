"""Shared fixtures for the simulation tests (headless rendering)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported anywhere

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tests.helpers.worlds import bundled_env  # noqa: E402


@pytest.fixture(scope="module")
def nominal_env():
    env = bundled_env("cup_on_plate")
    yield env
    env.close()


@pytest.fixture
def rng():
    return np.random.default_rng(0)
