"""Worlds from the experiment's config slices: the world's tasks and their environments."""

from __future__ import annotations

import dataclasses

from r2s_eval.errors import ConfigError
from r2s_eval.sim.env import TabletopEnv
from r2s_eval.sim.params import WorldParams
from r2s_eval.sim.robot import world_robot
from r2s_eval.sim.tasks import Task, get_task


def image_size(world_cfg: dict) -> tuple[int, int]:
    return int(world_cfg["image_height"]), int(world_cfg["image_width"])


def configured_task(key: str, world_cfg: dict, suite_cfg: dict | None) -> Task:
    """The world's task with the experiment's start regions, if the config sets any."""
    task = get_task(key, world_cfg)
    regions = ((suite_cfg or {}).get(key) or {}).get("init_regions")
    if not regions:
        return task
    new = dict(task.init_regions)
    for name, r in regions.items():
        if name not in new:
            raise ConfigError(f"suite.{key}.init_regions: task {key!r} has no object {name!r} (objects: {sorted(new)})")
        new[name] = dataclasses.replace(
            new[name], x_range_m=tuple(r["x_range_m"]), y_range_m=tuple(r["y_range_m"]),
            yaw_range_rad=tuple(r.get("yaw_range_rad", new[name].yaw_range_rad)),
        )
    return dataclasses.replace(task, init_regions=new)


def make_env(task: str, world_cfg: dict, params: WorldParams | None = None, cameras=None, suite_cfg: dict | None = None,
             **shared) -> TabletopEnv:
    """The task's environment as the ``world`` config slice describes it (image size, cameras);
    ``shared``: a compiled model and renderers to share (`TabletopEnv`)."""
    return TabletopEnv(
        configured_task(task, world_cfg, suite_cfg),
        params=params,
        image_size=image_size(world_cfg),
        cameras=tuple(world_cfg["cameras"] if cameras is None else cameras),
        robot=world_robot(world_cfg),
        **shared,
    )
