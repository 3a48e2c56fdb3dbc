"""The method's LIBERO setting: VLA checkpoints or policy servers ranked on LIBERO's tasks.

LIBERO runs in its own Python environment (`r2s_eval.libero.environment`); `libero_side.py` is
the part that runs there. `r2s_eval.libero.rollout` serves the candidate on loopback, starts the
LIBERO processes as its clients, and writes the same rollout folder as our own world's rollouts
(episodes.parquet, videos, trajectories), so judging, comparison, fit, validation and reports
need no LIBERO special case. The reference is LIBERO's own success rate.

This module holds the protocol: the suites, their step limits, and the task names episodes carry
(``<suite>_<index>``, e.g. ``libero_spatial_3``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from r2s_eval.errors import ConfigError

# Tasks per suite and the step limits LIBERO evaluations use (openpi's example: 220, 280, 300,
# 520, 400 control steps at 20 Hz).
SUITES: dict[str, tuple[int, int]] = {
    "libero_spatial": (10, 220),
    "libero_object": (10, 280),
    "libero_goal": (10, 300),
    "libero_10": (10, 520),
    "libero_90": (90, 400),
}
OFFICIAL_INIT_STATES = 50  # per task, shipped with LIBERO
CONTROL_HZ = 20
ACTION_DIM = 7  # 6-D end-effector delta + gripper
STATE_DIM = 8  # end-effector position (3) + axis-angle (3) + gripper fingers (2)
CAMERAS = ("agentview", "robot0_eye_in_hand")


@dataclass(frozen=True)
class LiberoTask:
    suite: str
    index: int
    max_steps: int

    @property
    def name(self) -> str:
        return f"{self.suite}_{self.index}"


def _split(task_name: str) -> tuple[str, int] | None:
    """(suite, index) of a task name of a known suite, else None (the index is not range-checked)."""
    suite, _, index = str(task_name).rpartition("_")
    return (suite, int(index)) if suite in SUITES and index.isdigit() else None


def suite_of(task_name: str) -> str:
    """The suite a task name belongs to (``libero_10_4`` -> ``libero_10``)."""
    parts = _split(task_name)
    if parts is None:
        raise ConfigError(f"{task_name!r} is not a LIBERO task name (<suite>_<index>; suites: {sorted(SUITES)})")
    return parts[0]


def selected_tasks(names: Sequence[str], max_steps: Mapping[str, int] | None = None) -> list[LiberoTask]:
    """The tasks `names` select, in the order given: a suite name stands for all its tasks, a
    task name (``<suite>_<index>``) for one. `max_steps`: step limits per suite (LIBERO's own
    where absent). Unknown names are errors listing the valid ones."""
    tasks: list[LiberoTask] = []
    for name in names:
        if name in SUITES:
            suite, indices = name, range(SUITES[name][0])
        else:
            parts = _split(name)
            if parts is None:
                raise ConfigError(f"libero.tasks: LIBERO has no suite or task {name!r}; suites: {sorted(SUITES)} "
                                  f"(all their tasks), or one task as <suite>_<index>")
            suite, index = parts
            if not index < SUITES[suite][0]:
                raise ConfigError(f"libero.tasks: {name!r} does not exist; {suite} has tasks "
                                  f"{suite}_0..{suite}_{SUITES[suite][0] - 1}")
            indices = [index]
        steps = int((max_steps or {}).get(suite) or SUITES[suite][1])
        tasks += [LiberoTask(suite, i, steps) for i in indices]
    names_seen = [t.name for t in tasks]
    repeated = sorted({n for n in names_seen if names_seen.count(n) > 1})
    if repeated:
        raise ConfigError(f"libero.tasks: {repeated} selected more than once")
    if not tasks:
        raise ConfigError("libero.tasks: no task selected")
    return tasks
