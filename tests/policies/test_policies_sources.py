"""Checkpoint and server candidates: config validation, content hashes, checks before rollouts."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from r2s_eval.horizon import Horizon
from r2s_eval.policies import ActionMap, PolicyError, PolicySpec, RecedingHorizon
from r2s_eval.errors import PolicyConfigError
from r2s_eval.policies.interface import ChunkPolicy
from r2s_eval.policy_sources import (
    check_checkpoint,
    check_server,
    checkpoint_hash,
    for_arm,
    result_identity,
    unwrap_variant,
    validate_candidate_cfg,
    validate_source_cfg,
)


def _checkpoint(folder, action_dim=14, inputs=None):
    folder.mkdir(parents=True)
    config = {"type": "act", "output_features": {"action": {"type": "ACTION", "shape": [action_dim]}},
              "input_features": inputs or {}}
    (folder / "config.json").write_text(json.dumps(config))
    (folder / "model.safetensors").write_bytes(os.urandom(4096))
    return folder


def test_source_configs_are_validated_with_names():
    with pytest.raises(PolicyConfigError, match=r"'lab'.*unknown key\(s\) \['pth'\]"):
        validate_source_cfg({"type": "checkpoint", "pth": "x"}, "lab")
    with pytest.raises(PolicyConfigError, match="no checkpoint path for the real arm"):
        validate_source_cfg({"type": "checkpoint", "arms": {"sim": {"path": "s"}}}, "lab")
    with pytest.raises(PolicyConfigError, match="no server port"):
        validate_source_cfg({"type": "server", "host": "gpu01"}, "srv")
    with pytest.raises(PolicyConfigError, match="arms are"):
        validate_source_cfg({"type": "server", "port": 1, "arms": {"hardware": {}}}, "srv")
    cfg = validate_source_cfg({"type": "server", "host": "gpu01", "port": 8000, "arms": {"sim": {"port": 8001}}}, "srv")
    assert (for_arm(cfg, "real")["port"], for_arm(cfg, "sim")["port"]) == (8000, 8001)
    # Where it runs is not what it is.
    assert {"host", "port", "api_key_env"}.isdisjoint(result_identity(for_arm(cfg, "sim")))


def test_a_snapshot_and_a_variant_of_one_open_the_trainings_weights():
    assert validate_candidate_cfg({"type": "snapshot", "of": "act", "step": 400}, "act_short") == {
        "type": "snapshot", "name": None, "of": "act", "step": 400}
    with pytest.raises(PolicyConfigError, match=r"policies\.act_short\.step.*got 2\.5"):
        validate_candidate_cfg({"type": "snapshot", "of": "act", "step": 2.5}, "act_short")
    # The workflow's candidate identities (workflow/rules/common.smk).
    snapshot = {"type": "snapshot", "of": "act", "step": 400, "weights": {"type": "act"}}
    execution = {"action_noise_std": 0.01}
    assert unwrap_variant(snapshot) == ({"type": "act"}, None)
    assert unwrap_variant({"type": "variant", "of": "act_short", "weights": snapshot, "execution": execution}) == (
        {"type": "act"}, execution)


def test_checkpoint_hash_follows_content_not_place(tmp_path):
    a = _checkpoint(tmp_path / "a")
    b = tmp_path / "b"
    b.mkdir()
    for f in a.iterdir():
        (b / f.name).write_bytes(f.read_bytes())
    memo = tmp_path / "memo.json"
    assert checkpoint_hash(a, memo) == checkpoint_hash(b, memo) == checkpoint_hash(b)
    assert len(json.loads(memo.read_text())) == 4  # two files in each folder, remembered
    (b / "model.safetensors").write_bytes(os.urandom(4096))
    assert checkpoint_hash(b, memo) != checkpoint_hash(a, memo)
    with pytest.raises(PolicyError, match="does not exist"):
        checkpoint_hash(tmp_path / "missing")


def test_bad_checkpoints_fail_before_any_rollout(tmp_path):
    with pytest.raises(PolicyError, match=r"policy 'lab'.*no LeRobot policy at"):
        check_checkpoint({"path": str(tmp_path / "nowhere")}, "lab", 14)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "config.json").write_text("{not json")
    with pytest.raises(PolicyError, match="not a LeRobot policy config"):
        check_checkpoint({"path": str(broken)}, "lab", 14)
    seven = _checkpoint(tmp_path / "seven", action_dim=7)
    with pytest.raises(PolicyError, match="7-D actions.*14-D; set action_map"):
        check_checkpoint({"path": str(seven)}, "lab", 14)
    with pytest.raises(PolicyError, match="7 distinct robot indices"):
        check_checkpoint({"path": str(seven), "action_map": [0, 1, 2]}, "lab", 14)
    info = check_checkpoint({"path": str(seven), "action_map": [0, 1, 2, 3, 4, 5, 6]}, "lab", 14)
    assert info["action_dim"] == 7 and info["type"] == "act"


def test_a_checkpoint_that_reads_what_the_world_does_not_record_fails_before_any_rollout(tmp_path):
    # A SO-101 policy (6-D, a front and a wrist camera) against a world recording one camera and
    # a 14-D state: each mismatch is named, with the world's side.
    inputs = {"observation.state": {"type": "STATE", "shape": [6]},
              "observation.images.front": {"type": "VISUAL", "shape": [3, 96, 96]},
              "observation.images.wrist": {"type": "VISUAL", "shape": [3, 96, 96]}}
    so101 = _checkpoint(tmp_path / "so101", action_dim=6, inputs=inputs)
    with pytest.raises(PolicyError) as error:
        check_checkpoint({"path": str(so101)}, "lab", 14, cameras=["front"], state_dim=14)
    message = str(error.value)
    assert "6-D actions, the robot takes 14-D" in message
    assert "reads cameras ['wrist'], which world.cameras ['front'] does not record" in message
    assert "reads a 6-D state, the world's robot records 14-D" in message
    assert check_checkpoint({"path": str(so101)}, "lab", 6, cameras=["front", "wrist"], state_dim=6)["action_dim"] == 6


def test_a_server_spec_or_key_map_that_reads_what_the_world_does_not_record_fails_when_planned():
    server = {"type": "server", "host": "gpu01", "port": 8000}
    spec = {"cameras": ["observation.images.top"], "state_dim": 8, "action_dim": 7, "max_chunk": 10}
    with pytest.raises(PolicyError) as error:
        check_server({**server, "spec": spec}, "srv", 6, cameras=["front", "wrist"], state_dim=6)
    message = str(error.value)
    assert message.startswith("policy 'srv' (server gpu01:8000): ")
    assert "reads cameras ['top']" in message and "8-D state" in message and "7-D actions" in message
    # openpi's DROID client: a camera the world lacks and joint positions beyond a 6-D state.
    droid = {**server, "preset": "openpi_droid", "keys": {"observation/exterior_image_1_left": {"camera": "top"},
                                                          "observation/wrist_image_left": {"camera": "wrist"}}}
    with pytest.raises(PolicyError, match=r"server key 'observation/exterior_image_1_left' reads camera 'top'"):
        check_server(droid, "srv", 8, cameras=["front", "wrist"], state_dim=8)
    with pytest.raises(PolicyError, match=r"server key 'observation/joint_position' reads .*beyond the 6-D state"):
        check_server({**droid, "keys": {**droid["keys"], "observation/exterior_image_1_left": {"camera": "front"}}},
                     "srv", 6, cameras=["front", "wrist"], state_dim=6)
    fitting = {**droid, "keys": {**droid["keys"], "observation/exterior_image_1_left": {"camera": "front"}}}
    check_server(fitting, "srv", 8, cameras=["front", "wrist"], state_dim=8)


class _Counting(ChunkPolicy):
    """A 7-D policy whose chunk k holds the value k everywhere."""

    name = "counting"
    spec = PolicySpec(cameras=(), action_dim=7, max_chunk=25, uses_state=True, state_dim=14)

    def __init__(self):
        self.calls = 0

    def predict_chunks(self, slots, observations):
        self.calls += 1
        return np.full((len(slots), 25, 7), float(self.calls), dtype=np.float32)


def test_action_map_drives_mapped_joints_and_holds_the_rest():
    policy = _Counting()
    with pytest.raises(PolicyError, match="7-D actions, the robot takes 14-D"):
        RecedingHorizon(policy, Horizon(25, 5), ActionMap(14))
    runner = RecedingHorizon(policy, Horizon(25, 5), ActionMap(14, tuple(range(7))))
    state = np.arange(14, dtype=np.float32) / 10
    actions = np.stack([runner.act({"observation.state": state}) for _ in range(6)])
    assert actions.shape == (6, 14) and policy.calls == 2
    np.testing.assert_array_equal(actions[:5, :7], 1.0)
    np.testing.assert_array_equal(actions[5, :7], 2.0)
    np.testing.assert_array_equal(actions[:, 7:], np.broadcast_to(state[7:], (6, 7)))
    runner.reset(seed=1)
    with pytest.raises(PolicyError, match=r"'counting' needs \['observation.state'\]"):
        runner.act({})
