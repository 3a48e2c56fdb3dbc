"""LIBERO's own environment and two tiny VLA checkpoints, shared by the LIBERO tests.

The environment is made by the project's own code (``r2s_eval.libero.environment``) the first
time, from the pinned requirements (a few minutes; the package index must be reachable then),
and reused afterwards. Tests that need it are marked ``libero``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from r2s_eval.libero import environment

TINY_CAMERAS = ["observation.images.image", "observation.images.wrist_image"]


@pytest.fixture(scope="session")
def libero_python() -> Path:
    return environment.ensure(environment.env_dir(None))


@pytest.fixture(scope="session")
def tiny_checkpoints(tmp_path_factory) -> dict[str, Path]:
    from r2s_eval.policies.tiny import build_tiny_checkpoint

    base = tmp_path_factory.mktemp("tiny_vla")
    return {name: build_tiny_checkpoint(base / name, cameras=TINY_CAMERAS, state_dim=8, action_dim=7, chunk_size=25,
                                        seed=seed)
            for seed, name in enumerate(("tiny_a", "tiny_b"))}
