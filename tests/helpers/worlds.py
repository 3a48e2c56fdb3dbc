"""The bundled world (``conf/world/tabletop.yaml``) as the tests use it: its config, robot, tasks,
environments and twins. The library takes a world from its caller and never falls back to this
one; a test names it here (or through the ``bundled_world`` fixture of ``tests/conftest.py``)."""

from __future__ import annotations

import copy
import functools

import numpy as np

from r2s_eval.sim import TabletopEnv, WorldParams, get_task, world_config, world_robot
from r2s_eval.sim.robot import Robot
from r2s_eval.sim.tasks import Task, world_tasks
from r2s_eval.twin.perturb import TwinMagnitudes, sample_reality_effects, sample_twin_params
from r2s_eval.twin.reality import RealityEffects, RealityEnv

BUNDLED = "tabletop"


@functools.cache
def _bundled_world() -> dict:
    return world_config(BUNDLED)


def bundled_world() -> dict:
    """The bundled world's config, a fresh copy the caller may change."""
    return copy.deepcopy(_bundled_world())


def bundled_robot() -> Robot:
    return world_robot(_bundled_world())


def bundled_tasks() -> dict[str, Task]:
    return world_tasks(_bundled_world())


def bundled_env(task: str = "cup_on_plate", params: WorldParams | None = None, **kwargs) -> TabletopEnv:
    """``TabletopEnv`` of the bundled world's task ``task`` (``kwargs``: its other arguments)."""
    return TabletopEnv(get_task(task, _bundled_world()), params, robot=bundled_robot(), **kwargs)


def bundled_twin_env(task: str = "cup_on_plate", params: WorldParams | None = None,
                     reality: RealityEffects | None = None, **kwargs) -> RealityEnv:
    """The twin's environment (``RealityEnv``) of the bundled world's task ``task``: world
    parameters ``params`` with the ``reality`` effects around them (``kwargs``: the rest)."""
    return RealityEnv(get_task(task, _bundled_world()), params, reality, robot=bundled_robot(), **kwargs)


def bundled_reality(rng: np.random.Generator, magnitudes: TwinMagnitudes | None = None) -> RealityEffects:
    """A twin's reality effects for the bundled world (``sample_reality_effects``)."""
    return sample_reality_effects(rng, magnitudes, robot=bundled_robot())


def bundled_twin(rng: np.random.Generator, magnitudes: TwinMagnitudes | None = None,
                 object_names: tuple[str, ...] | None = None) -> WorldParams:
    """A twin of the bundled world (``sample_twin_params``), perturbing all its objects unless
    ``object_names`` are given."""
    names = tuple(sorted(_bundled_world()["objects"])) if object_names is None else object_names
    return sample_twin_params(rng, magnitudes, object_names=names, robot=bundled_robot())
