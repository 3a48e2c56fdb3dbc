"""The seeded initial configurations every policy is evaluated from."""

from __future__ import annotations

import numpy as np
import pandas as pd

from r2s_eval.sim import Task
from r2s_eval.sim.tasks import sample_initial_poses


def sample_inits(tasks: list[Task], inits_per_task: int, seed: int) -> pd.DataFrame:
    """One row per (task, init_id, object) with a planar pose; the same for all policies."""
    rows = []
    for task_index, task in enumerate(tasks):
        rng = np.random.default_rng([seed, task_index, 7])
        for init_id in range(inits_per_task):  # in the nominal world: objects at their own size
            for name, (x, y, yaw) in sample_initial_poses(task, rng).items():
                rows.append({"task": task.key, "init_id": init_id, "object": name, "x_m": x, "y_m": y, "yaw_rad": yaw})
    return pd.DataFrame(rows)


def poses_of(inits: pd.DataFrame, task: str, init_id: int) -> dict[str, tuple[float, float, float]]:
    rows = inits[(inits["task"] == task) & (inits["init_id"] == init_id)]
    return {r.object: (float(r.x_m), float(r.y_m), float(r.yaw_rad)) for r in rows.itertuples()}


def episode_seed(seed: int, init_id: int) -> int:
    """The seed of the episode from init ``init_id`` (its image and encoder noise, the policy's
    draws), from the experiment's ``seed``: the same for every policy and arm."""
    return int(np.random.default_rng([int(seed), int(init_id)]).integers(2**31))
