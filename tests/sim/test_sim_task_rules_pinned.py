"""The tasks' success and progress rules give the answers pinned before they became world
predicates (`tests/helpers/task_rule_states.py` recorded the states and the hand-written rules' answers)."""

from __future__ import annotations

from collections import defaultdict

import pytest


from tests.helpers.task_rule_states import evaluate, load, world_params
from tests.helpers.worlds import bundled_env, bundled_tasks

TASKS = bundled_tasks()


@pytest.mark.parametrize("task", sorted(TASKS))
def test_rules_give_the_pinned_answers_on_every_state(task):
    states = [s for s in load() if s["task"] == task]
    assert len(states) > 150
    by_world = defaultdict(list)
    for state in states:
        by_world[state["twin_seed"]].append(state)
    differ = []
    for twin_seed, world_states in by_world.items():
        env = bundled_env(task, params=world_params(task, twin_seed), cameras=())
        names = env.task.object_names
        for k, state in enumerate(world_states):
            start_z = dict(zip(names, state["initial_centre_z_m"], strict=True))
            answer = evaluate(env, state["qpos"], state["qvel"], start_z)
            if answer != (state["success"], state["progress"]):
                differ.append((twin_seed, k, answer, (state["success"], state["progress"])))
        env.close()
    assert differ == [], f"{len(differ)} of {len(states)} states differ, e.g. {differ[:5]}"
    # The states reach every stage, so every part of the rules is checked.
    assert {s["progress"] for s in states} == {0.0, 0.2, 0.4, 0.6, 0.8, 1.0}
