"""Planted quality: a variant's commands differ from its base's only by the stated change, and
nothing of the variant reaches a judge."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from r2s_eval.errors import PolicyConfigError
from r2s_eval.judge import KinematicJudge, describe_rollouts
from r2s_eval.rollout import sample_inits
from r2s_eval.rollout.candidate import run_candidate
from r2s_eval.policies.execution import _NOISE_STREAM, Execution, complete_execution
from r2s_eval.sim import get_task, world_robot
from tests.helpers.worlds import bundled_world
from r2s_eval.utils.numerics import deterministic_torch
from tests.helpers.policies import save_random_policy

JOINTS, GRIPPERS = (0, 1, 2, 4, 5, 6), (3, 7)


def _stream(n: int = 40, dim: int = 8) -> list[np.ndarray]:
    return [np.arange(dim, dtype=np.float32) + 0.01 * k for k in range(n)]


def _executed(execution: dict, n_out: int, seed: int = 5, **grippers) -> tuple[np.ndarray, int]:
    """The first `n_out` commands sent for the scripted stream, and how many it took from it."""
    stream = iter(_stream())
    taken = []

    def pop():
        taken.append(1)
        return next(stream)

    commands = Execution.from_config(execution, JOINTS, GRIPPERS, **grippers).start(seed)
    return np.array([commands.next(pop) for _ in range(n_out)]), len(taken)


def test_jitter_changes_the_arm_joints_only_by_the_episode_seeds_draws():
    sent, taken = _executed({"action_noise_std": 0.01}, 10)
    base = np.array(_stream()[:10])
    rng = np.random.default_rng([5, _NOISE_STREAM])
    expected = base.astype(np.float64)
    for k in range(10):
        expected[k, list(JOINTS)] += rng.normal(0.0, 0.01, len(JOINTS))
    assert taken == 10 and sent.dtype == np.float32
    np.testing.assert_array_equal(sent[:, list(GRIPPERS)], base[:, list(GRIPPERS)])
    np.testing.assert_allclose(sent, expected.astype(np.float32), atol=1e-7)
    assert np.abs(sent - base)[:, list(JOINTS)].max() > 0
    # Same seed, same draws; another episode's seed, others.
    assert np.array_equal(_executed({"action_noise_std": 0.01}, 10)[0], sent)
    assert not np.array_equal(_executed({"action_noise_std": 0.01}, 10, seed=6)[0], sent)


def test_hesitation_inserts_pauses_and_skips_nothing():
    sent, taken = _executed({"hesitate": {"every_steps": 3, "pause_steps": 2}}, 13)
    base = np.array(_stream())
    # Three commands, the third held for two more steps, three more, ...
    order = [0, 1, 2, 2, 2, 3, 4, 5, 5, 5, 6, 7, 8]
    np.testing.assert_array_equal(sent, base[order])
    assert taken == 9


def test_a_late_gripper_gets_its_commands_k_steps_late():
    sent, _ = _executed({"gripper_delay_steps": 3}, 12)
    base = np.array(_stream()[:12])
    np.testing.assert_array_equal(sent[:, list(JOINTS)], base[:, list(JOINTS)])
    delayed = np.array([base[max(0, k - 3), list(GRIPPERS)] for k in range(12)])
    np.testing.assert_array_equal(sent[:, list(GRIPPERS)], delayed)


def test_a_lowpass_filters_the_joints_and_leaves_the_grippers():
    sent, _ = _executed({"lowpass": 0.5}, 6)
    base = np.array(_stream()[:6], dtype=np.float64)
    filtered = base[0, list(JOINTS)]
    for k in range(1, 6):
        filtered = 0.5 * filtered + 0.5 * base[k, list(JOINTS)]
        np.testing.assert_allclose(sent[k, list(JOINTS)], filtered, atol=1e-6)
    np.testing.assert_array_equal(sent[:, list(GRIPPERS)], base[:, list(GRIPPERS)].astype(np.float32))


def _gripper_commands(closing: list[list[float]], execution: dict, opened=(0.0, 1.0), closed=(1.0, 0.0)):
    """The gripper commands sent for a scripted stream whose grippers' closing follows ``closing``
    (per step, per gripper; the second gripper's units run the other way, as ALOHA's do)."""
    opened, closed = np.array(opened), np.array(closed)
    stream = iter([np.r_[np.zeros(3), opened[0] + c[0] * (closed[0] - opened[0]), np.zeros(3),
                         opened[1] + c[1] * (closed[1] - opened[1])].astype(np.float32) for c in closing])
    commands = Execution.from_config(execution, JOINTS, GRIPPERS, gripper_open=opened, gripper_closed=closed).start(5)
    sent = np.array([commands.next(lambda: next(stream)) for _ in closing])[:, list(GRIPPERS)]
    return (sent - opened) / (closed - opened)  # back to closing: 0 open, 1 closed


def test_a_fumbling_gripper_opens_once_for_n_steps_after_k_closed_steps():
    # Open for 5 steps, half-closed (not yet closed) for 2, closed for the rest of 40.
    closing = [[0.0, 0.0]] * 5 + [[0.3, 0.3]] * 2 + [[1.0, 1.0]] * 33
    sent = _gripper_commands(closing, {"fumble": {"after_steps": 4, "open_steps": 3}})
    expected = np.array(closing)
    expected[7 + 4:7 + 4 + 3] = 0.0  # closed from step 7: steps 7..10 go out, then 3 open, then closed for good
    np.testing.assert_allclose(sent, expected, atol=1e-7)
    # Only part of the way open: the policy's closing less `opening`.
    sent = _gripper_commands(closing, {"fumble": {"after_steps": 4, "open_steps": 3, "opening": 0.25}})
    expected[7 + 4:7 + 4 + 3] = 0.75
    np.testing.assert_allclose(sent, expected, atol=1e-7)


def test_a_fumble_waits_for_the_gripper_to_be_closed_k_steps_in_a_row_and_each_gripper_fumbles_once():
    # The first gripper closes twice for 2 steps (too short), then for good at step 10; the second
    # closes at step 3, opens at step 20 (the policy lets go) and closes again at 25.
    first = [0.0] * 3 + [1.0] * 2 + [0.0] * 2 + [1.0] * 2 + [0.0] + [1.0] * 30
    second = [0.0] * 3 + [0.9] * 17 + [0.0] * 5 + [0.9] * 15
    sent = _gripper_commands(list(zip(first, second)), {"fumble": {"after_steps": 3, "open_steps": 2}})
    expected = np.array([first, second]).T
    expected[13:15, 0] = 0.0
    expected[6:8, 1] = 0.0  # its second closing, after 20, goes out as the policy's: once per episode
    np.testing.assert_allclose(sent, expected, atol=1e-6)
    # Never closed long enough: the policy's commands throughout.
    never = [[float(k % 3 == 0), 0.4] for k in range(30)]
    np.testing.assert_allclose(_gripper_commands(never, {"fumble": {"after_steps": 2, "open_steps": 5}}), never,
                               atol=1e-7)


def test_a_fumble_leaves_the_arm_joints_and_needs_the_grippers_open_and_closed_commands():
    sent, taken = _executed({"fumble": {"after_steps": 1, "open_steps": 1}}, 10, gripper_open=(0, 0),
                            gripper_closed=(10, 10))
    base = np.array(_stream()[:10])
    np.testing.assert_array_equal(sent[:, list(JOINTS)], base[:, list(JOINTS)])
    assert taken == 10 and (sent[:, list(GRIPPERS)] != base[:, list(GRIPPERS)]).sum() == 1  # the 7 closes at once
    with pytest.raises(PolicyConfigError, match="fumble needs each gripper's distinct open and closed"):
        Execution.from_config({"fumble": {"after_steps": 1, "open_steps": 1}}, JOINTS, GRIPPERS)


def _step_response(overshoot: float, n: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """Commands sent when the policy's joint targets step from 0 to 1 (to -2 on joint 1) at step 5."""
    step = np.zeros(8, dtype=np.float32)
    step[list(JOINTS)] = 1.0
    step[1] = -2.0
    step[list(GRIPPERS)] = 0.5
    targets = [np.zeros(8, dtype=np.float32)] * 5 + [step] * (n - 5)
    stream = iter(targets)
    commands = Execution.from_config({"overshoot": overshoot}, JOINTS, GRIPPERS).start(5)
    return np.array([commands.next(lambda: next(stream)) for _ in range(n)]), np.array(targets)


@pytest.mark.parametrize("overshoot", [0.02, 0.2, 0.6])
def test_an_overshooting_servo_passes_a_step_by_f_and_settles_back(overshoot):
    sent, targets = _step_response(overshoot, n=300 if overshoot > 0.5 else 80)
    np.testing.assert_array_equal(sent[:, list(GRIPPERS)], targets[:, list(GRIPPERS)])  # grippers untouched
    np.testing.assert_array_equal(sent[:5], targets[:5])  # it starts on the first command: no jump
    joints = sent[:, list(JOINTS)] / targets[-1, list(JOINTS)]  # each joint's response to a unit step
    # The peak is sampled where it lies (3 steps after the last command before the step: steps 5, 6,
    # 7), so it passes the target by F up to float32 rounding; no sample passes it by more.
    assert np.all(np.argmax(joints, axis=0) == 7)
    np.testing.assert_allclose(joints.max(axis=0) - 1.0, overshoot, atol=1e-6)
    assert np.all(joints[5] > 0) and np.all(joints[5] < 1)  # the first step moves towards the target
    # Then it rings back below the target and settles on it.
    assert np.all(joints[8:].min(axis=0) < 1.0)
    np.testing.assert_allclose(joints[-5:], 1.0, atol=1e-4)


def test_changes_combine_and_with_all_switched_off_the_commands_are_the_policys_bit_for_bit():
    everything = {"action_noise_std": 0.01, "hesitate": {"every_steps": 4, "pause_steps": 1}, "gripper_delay_steps": 1,
                  "lowpass": 0.3, "fumble": {"after_steps": 2, "open_steps": 2, "opening": 0.5}, "overshoot": 0.1}
    sent, taken = _executed(everything, 20, gripper_open=(0, 0), gripper_closed=(10, 10))
    assert np.isfinite(sent).all() and taken == 16  # 4 pauses
    # Gripper 7 (closing 0.7 in these units: closed from the start) is opened half-way at the policy's
    # third and fourth commands, which reach it a step late; the pause after the fourth command holds it.
    assert list(np.flatnonzero(sent[:, 7] < 6.0)) == [3, 4, 5]
    np.testing.assert_allclose(sent[3:6, 7], [2.02, 2.02, 2.03], atol=1e-5)  # 10 * (0.7 + 0.01 k / 10 - 0.5)
    # With every change off (which a config cannot ask for) the commands are the policy's, bit for bit.
    off = Execution(action_noise_std=0.0, hesitate=None, gripper_delay_steps=0, lowpass=0.0, fumble=None,
                    overshoot=0.0, joints=JOINTS, grippers=GRIPPERS)
    stream = _stream()
    queue = iter(stream)
    commands = off.start(5)
    sent = np.array([commands.next(lambda: next(queue)) for _ in range(len(stream))])
    assert sent.dtype == np.float32 and sent.tobytes() == np.array(stream).tobytes()


@pytest.mark.parametrize("execution, message", [
    ({}, "changes nothing"),
    ({"overshoot": 0.0}, "changes nothing"),
    ({"overshoot": -0.1}, r"overshoot must be in \[0, 1\)"),
    ({"overshoot": 1.0}, r"overshoot must be in \[0, 1\)"),
    ({"fumble": {"after_steps": 5}}, "fumble must be {after_steps: K, open_steps: N}"),
    ({"fumble": {"after_steps": 5, "open_steps": 0}}, "fumble must be"),
    ({"fumble": {"after_steps": 2.5, "open_steps": 1}}, "fumble must be"),
    ({"fumble": {"after_steps": 2, "open_steps": 1, "opening": 0}}, "fumble must be"),
    ({"fumble": {"after_steps": 2, "open_steps": 1, "opening": 1.5}}, "fumble must be"),
    ({"fumble": {"after_steps": 2, "open_steps": 1, "closing": 1}}, "fumble must be"),
    ({"fumble": 3}, "fumble must be"),
    ({"action_noise": 0.1}, r"unknown key\(s\) \['action_noise'\]"),
    ({"lowpass": 1.0}, r"lowpass must be in \[0, 1\)"),
    ({"hesitate": {"every_steps": 5}}, "every_steps: N, pause_steps: P"),
    ({"gripper_delay_steps": -1}, "gripper_delay_steps must be >= 0"),
])
def test_an_execution_that_is_wrong_or_changes_nothing_names_the_key(execution, message):
    with pytest.raises(PolicyConfigError, match=message):
        complete_execution(execution, "policies.act_shaky")


# -- through the rollout stage ---------------------------------------------------------------

TASKS = ["cup_on_plate", "stack_blocks"]
WORLD = {**bundled_world(), "image_height": 48, "image_width": 48, "cameras": ["head_left"]}
ROLLOUT = {"horizon": {"chunk": 10, "execute": 5}, "inits_per_task": 2, "real_inits_per_task": None, "max_duration_s": 1.2,
           "device": "cpu", "model_batch": 4, "video_camera": "head_left", "video_size": [64, 64],
           "real_video_size": None, "video_fps": 10}
SEED = 3
SHAKY = {"type": "variant", "of": "act", "weights": {"type": "act"},
         "execution": complete_execution({"action_noise_std": 0.02}, "policies.act_shaky")}


def test_a_variant_runs_its_bases_weights_with_the_stated_change_and_a_judge_sees_none_of_it(tmp_path):
    inits = tmp_path / "inits.parquet"
    sample_inits([get_task(t, WORLD) for t in TASKS], ROLLOUT["inits_per_task"], SEED).to_parquet(inits)
    act = save_random_policy(tmp_path / "weights", WORLD["cameras"], (48, 48))

    def run(policy, policy_cfg):
        deterministic_torch(1)
        return run_candidate(tmp_path / policy, policy=policy, arm="sim", seed=SEED, rollout=ROLLOUT, world=WORLD,
                             policy_cfg=policy_cfg, inits=str(inits), trained_dir=str(act), batch_episodes=2)

    base, shaky = run("act", {"type": "act"}), run("act_shaky", SHAKY)
    features = world_robot(WORLD).features  # the bundled world: 6 joints and a gripper per arm
    robot_joints = [i for i, f in enumerate(features) if f.joint is not None]
    robot_grippers = [i for i, f in enumerate(features) if f.joint is None]
    assert robot_grippers == [6, 13]
    assert list(base["init_id"]) == list(shaky["init_id"]) and list(base["seed"]) == list(shaky["seed"])
    for (_, b), (_, v) in zip(base.iterrows(), shaky.iterrows()):
        first_b = np.stack(pd.read_parquet(tmp_path / "act" / b["trajectory_path"])["action"].to_numpy())[0]
        first_v = np.stack(pd.read_parquet(tmp_path / "act_shaky" / v["trajectory_path"])["action"].to_numpy())[0]
        # Same seed, same first observation: the same model output, then the episode's own noise.
        noise = np.random.default_rng([int(v["seed"]), _NOISE_STREAM]).normal(0.0, 0.02, len(robot_joints))
        np.testing.assert_array_equal(first_v[robot_grippers], first_b[robot_grippers])
        np.testing.assert_allclose(first_v[robot_joints], first_b[robot_joints] + noise, atol=1e-6)
        assert not np.array_equal(first_v, first_b)

    # What a judge receives of the variant's rollouts: the instruction and content-named recordings.
    seen = []

    class Spy(KinematicJudge):
        inputs = ("video", "trajectory")

        def describe(self, rollout):
            seen.append((rollout, rollout.video_path.read_bytes() + rollout.trajectory_path.read_bytes()))
            return super().describe(rollout)

    describe_rollouts(shaky, tmp_path / "act_shaky", Spy({"backend": "kinematic"}), tmp_path / "cache")
    assert len(seen) == len(shaky)
    for rollout, files in seen:
        visible = " ".join((rollout.instruction, rollout.video_path.name, rollout.trajectory_path.name)).encode()
        for secret in (b"act_shaky", b"variant", b"action_noise_std", b"execution", b"0.02"):
            assert secret not in visible and secret not in files, secret


def test_a_variant_of_no_candidate_is_a_config_error_naming_the_key():
    from pathlib import Path

    from r2s_eval.config import compose_config
    from r2s_eval.errors import ConfigError

    conf = Path(__file__).resolve().parents[2] / "conf"
    shaky = "+policies.act_shaky={type: variant, of: %s, execution: {action_noise_std: 0.01}}"
    cfg = compose_config(conf, "smoke", overrides=[shaky % "act"])
    assert cfg["policies"]["act_shaky"]["of"] == "act"
    with pytest.raises(ConfigError, match=r"policies\.act_shaky\.of.*'actt'"):
        compose_config(conf, "smoke", overrides=[shaky % "actt"])
    with pytest.raises(ConfigError, match=r"policies\.act_shaky\.execution.*lowpass"):
        compose_config(conf, "smoke", overrides=["+policies.act_shaky={type: variant, of: act, execution: {lowpass: 2}}"])
