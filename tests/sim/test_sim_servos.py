"""The simulated servos: a nominal world acts on each command at once and exactly; the calibrated
sim's answer to a robot's latency (``WorldParams.command_latency_steps``) delays every command by
whole control steps. The twin's own late, loose and weak servos: ``test_sim_twin_servos.py``."""

import dataclasses
import json

import numpy as np
import pytest

from r2s_eval.errors import ConfigError
from r2s_eval.sim import WorldParams, load_world_params
from r2s_eval.sim.build import check_world_params
from tests.helpers.commands import POSES, run, wandering_commands
from tests.helpers.worlds import bundled_env, bundled_world


@pytest.mark.parametrize("latency", [1, 2])
def test_a_late_command_is_the_nominal_target_trajectory_shifted(latency):
    nominal = bundled_env("cup_on_plate", cameras=())
    late = bundled_env("cup_on_plate", params=WorldParams(command_latency_steps=latency), cameras=())
    commands = wandering_commands(nominal, 12, seed=latency)
    late.reset(POSES, seed=0, observe=False)
    at_reset = late.data.ctrl.copy()
    targets, _ = run(nominal, commands)
    late_targets, _ = run(late, commands)
    # Until the first command arrives the servos hold their reset targets, then each arrives
    # `latency` steps late, exactly.
    assert np.array_equal(late_targets[:latency], np.broadcast_to(at_reset, (latency, at_reset.size)))
    assert np.array_equal(late_targets[latency:], targets[:-latency])
    # A new episode starts with nothing under way: the last episode's commands never arrive.
    late.reset(POSES, seed=0, observe=False)
    late.step(commands[0], images=False)
    assert np.array_equal(late.data.ctrl, at_reset)
    nominal.close()
    late.close()


def test_a_nominal_world_acts_on_each_command_at_once_and_exactly():
    env = bundled_env("cup_on_plate", cameras=())
    commands = wandering_commands(env, 8, seed=5)
    targets, _ = run(env, commands)
    for command, target in zip(commands, targets):
        for arm, (q, _) in env.robot.to_model(command).items():
            actuators = [env.model.actuator(env.robot.arms[arm].named(a)).id for a in env.robot.arms[arm].actuators]
            lo, hi = env.model.actuator_ctrlrange[actuators].T
            assert np.array_equal(target[actuators], np.clip(q, lo, hi))
    env.close()


def test_the_latency_answer_round_trips_and_is_a_whole_number_of_steps(tmp_path):
    params = WorldParams(command_latency_steps=2)
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"params": dataclasses.asdict(params)}))
    back = load_world_params(path)
    assert back == params and isinstance(back.command_latency_steps, int)
    check_world_params(back, bundled_world(), "params.json")
    for wrong in (-1, 1.5):
        with pytest.raises(ConfigError, match=r"^params.json: command_latency_steps must be a whole number"):
            check_world_params(WorldParams(command_latency_steps=wrong), bundled_world(), "params.json")
