"""Pinned states of the seven tasks and what the task rules said of them.

`python -m tests.helpers.task_rule_states` (from the repository root) records scripted-operator
episodes of every task, in the nominal world and in twin worlds (whose objects are resized and whose
joints are offset, so some episodes fail), keeps every other control step's physics state and
evaluates the tasks' success and progress on it, and writes them to
`tests/sim/data/task_rule_states.npz`. It was run once with the rules as hand-written Python
functions, before they became predicates of the world config: tests/sim/test_sim_task_rules_pinned.py
checks that the rules of today give the same answers on the same states.

A state is evaluated after `mj_forward`, so its contacts are those of its own positions: a pure
function of (qpos, qvel), whatever the simulation did before.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from r2s_eval.sim import TabletopEnv  # noqa: E402
from r2s_eval.twin.operator import make_operator  # noqa: E402
from tests.helpers.worlds import bundled_env, bundled_tasks, bundled_twin  # noqa: E402

TASKS = bundled_tasks()

PINNED = Path(__file__).resolve().parents[1] / "sim" / "data" / "task_rule_states.npz"
EPISODES = {"nominal": 2, "twin": 3}
KEEP_EVERY = 2
MAX_STEPS = 150


def world_params(task: str, twin_seed: int):
    """The episode's world: nominal (twin_seed < 0) or a sampled twin."""
    if twin_seed < 0:
        return None
    return bundled_twin(np.random.default_rng([twin_seed, 1]), object_names=TASKS[task].object_names)


def evaluate(env: TabletopEnv, qpos: np.ndarray, qvel: np.ndarray, initial_centre_z_m: dict) -> tuple[bool, float]:
    """The task's success and progress of one state."""
    env.data.qpos[:] = qpos
    env.data.qvel[:] = qvel
    mujoco.mj_forward(env.model, env.data)
    env.initial_centre_z_m = dict(initial_centre_z_m)
    return bool(env.task.success(env)), float(env.task.progress(env))


def record() -> dict[str, np.ndarray]:
    rows: dict[str, list] = {k: [] for k in ("task", "twin_seed", "episode", "qpos", "qvel", "initial_centre_z_m",
                                             "success", "progress")}
    for t, task in enumerate(sorted(TASKS)):
        for kind, count in EPISODES.items():
            for i in range(count):
                twin_seed = 1000 * t + i if kind == "twin" else -1
                env = bundled_env(task, params=world_params(task, twin_seed), cameras=())
                obs = env.reset(seed=100 * t + i + (50 if kind == "twin" else 0))
                start_z = dict(env.initial_centre_z_m)
                operator = make_operator(task, env, np.random.default_rng([t, i, kind == "twin"]))
                states = []
                for step in range(MAX_STEPS):
                    if step % KEEP_EVERY == 0:
                        states.append((env.data.qpos.copy(), env.data.qvel.copy()))
                    action = operator.act(obs)
                    if operator.done:
                        break
                    obs = env.step(action, images=False)
                states.append((env.data.qpos.copy(), env.data.qvel.copy()))  # the final state
                for qpos, qvel in states:
                    success, progress = evaluate(env, qpos, qvel, start_z)
                    for key, value in (("task", task), ("twin_seed", twin_seed), ("episode", i), ("qpos", qpos),
                                       ("qvel", qvel), ("initial_centre_z_m", [start_z[n] for n in TASKS[task].object_names]),
                                       ("success", success), ("progress", progress)):
                        rows[key].append(value)
                env.close()
    out = {k: np.array(v) for k, v in rows.items() if k not in ("qpos", "qvel", "initial_centre_z_m")}
    for key in ("qpos", "qvel", "initial_centre_z_m"):  # widths differ by task: one flat array and offsets
        out[key] = np.concatenate(rows[key])
        out[f"{key}_offsets"] = np.cumsum([0, *(len(v) for v in rows[key])])
    return out


@functools.cache
def load() -> list[dict]:
    """The pinned states, one dict each (task, twin_seed, qpos, qvel, initial_centre_z_m, success, progress)."""
    data = np.load(PINNED)
    states = []
    for k in range(len(data["task"])):
        state = {key: data[key][k].item() for key in ("task", "twin_seed", "episode", "success", "progress")}
        for key in ("qpos", "qvel", "initial_centre_z_m"):
            lo, hi = data[f"{key}_offsets"][k], data[f"{key}_offsets"][k + 1]
            state[key] = data[key][lo:hi]
        states.append(state)
    return states


if __name__ == "__main__":
    pinned = record()
    PINNED.parent.mkdir(exist_ok=True)
    np.savez_compressed(PINNED, **pinned)
    for task in sorted(TASKS):
        mine = pinned["task"] == task
        levels, counts = np.unique(pinned["progress"][mine], return_counts=True)
        print(f"{task}: {mine.sum()} states, {pinned['success'][mine].sum()} successful, progress "
              + ", ".join(f"{lv:.1f}x{c}" for lv, c in zip(levels, counts)))
    print(f"{PINNED}: {PINNED.stat().st_size / 1e6:.2f} MB")
