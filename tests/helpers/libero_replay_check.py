"""Run in LIBERO's environment: replay recorded actions from an episode's initial state and
report LIBERO's own success check and the end-effector position at the last step.

    <libero-env>/bin/python libero_replay_check.py EPISODE.json WORLD_SCRIPT

It is a script, never imported: LIBERO's interpreter has neither r2s_eval nor this package, so the
world script (r2s_eval/libero/libero_side.py, which imports only the standard library, numpy, LIBERO
and openpi-client) is loaded by path.
"""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

spec = importlib.util.spec_from_file_location("world", sys.argv[2])
world = importlib.util.module_from_spec(spec)
spec.loader.exec_module(world)

ep = json.loads(Path(sys.argv[1]).read_text())
task, bddl, init_states = world.task_of(ep["suite"], ep["task_index"])
env = world.make_env(bddl, "on_demand", (64, 64), ["agentview"])
env.seed(ep["seed"])
env.reset()
obs = env.set_init_state(init_states[ep["init_index"]])
for _ in range(ep["settle_steps"]):
    obs, _, _, _ = env.step(world.SETTLE_ACTION)
for action in ep["actions"]:
    obs, _, _, _ = env.step(action)
print(json.dumps({"success": bool(env.check_success()), "eef_pos": np.asarray(obs["robot0_eef_pos"]).tolist()}))
env.close()
