"""Server candidates' key maps and specs in the config: the schema types them, the owner's
validator names the policy and the key, and open_policy hands them to the client."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from r2s_eval.errors import PolicyConfigError
from r2s_eval.policy_sources import for_arm, open_policy, result_identity, validate_source_cfg

CONF = Path(__file__).resolve().parents[2] / "conf"
DROID_CAMERAS = {"observation/exterior_image_1_left": {"camera": "front"},
                 "observation/wrist_image_left": {"camera": "wrist"}}


def _server(**kw) -> dict:
    return {"type": "server", "host": "gpu01", "port": 8000, **kw}


def test_server_keys_validate_and_decide_results():
    cfg = validate_source_cfg(_server(preset="openpi_droid", keys=DROID_CAMERAS, spec={"max_chunk": 10}), "droid")
    identity = result_identity(for_arm(cfg, "sim"))
    # What the server is shown decides its results; where it runs does not.
    assert identity["preset"] == "openpi_droid" and identity["keys"] == DROID_CAMERAS
    assert validate_source_cfg(_server(), "plain")["keys"] is None
    policy = open_policy(for_arm(cfg, "sim"), "droid")  # a whole spec: no connection is made
    try:
        assert policy.key_map.preset == "openpi_droid"
        assert policy.spec.cameras == ("observation.images.front", "observation.images.wrist")
        assert (policy.spec.action_dim, policy.spec.max_chunk) == (8, 10)
    finally:
        policy.close()


def test_server_key_left_unfilled_is_a_config_error():
    with pytest.raises(PolicyConfigError) as caught:
        validate_source_cfg(_server(preset="openpi_droid"), "droid")
    message = str(caught.value)
    assert message.startswith("policy 'droid': ")
    assert "server key 'observation/exterior_image_1_left' ('preset': openpi_droid) is filled by nothing (camera missing)" in message
    assert "'observation/wrist_image_left'" in message
    # Per arm: the real arm's server has its own map, checked on its own.
    arms = {"real": {"keys": {"observation/exterior_image_1_left": {"camera": "front"}}}, "sim": {"keys": DROID_CAMERAS}}
    with pytest.raises(PolicyConfigError, match=r"'droid'.*'observation/wrist_image_left'.*camera missing"):
        validate_source_cfg(_server(preset="openpi_droid", arms=arms), "droid")


@pytest.mark.parametrize("entry, match", [
    (_server(spec={"max_chunks": 10}), r"'spec' has unknown field\(s\) \['max_chunks'\]"),
    (_server(preset="openpi_libero", spec={"cameras": ["observation.images.image"]}),
     r"'spec' sets \['cameras'\], which its key map"),
    (_server(keys={"prompt": {"instruction": True, "state": True}}), r"'prompt' names 2 streams"),
    (_server(preset="openpi_libro"), r"'preset' must be one of \['openpi_droid', 'openpi_libero'\]"),
    (_server(keys=["observation/image"]), r"'keys' must map each server key"),
])
def test_server_entry_faults_name_policy_and_key(entry, match):
    with pytest.raises(PolicyConfigError, match=r"^policy 'srv'.*" + match):
        validate_source_cfg(entry, "srv")


@pytest.fixture(scope="module")
def smoke_cfg():
    from r2s_eval.config import compose_config

    return compose_config(CONF, "smoke")


def test_server_spec_and_keys_are_schema_checked(smoke_cfg):
    from r2s_eval.schema import config_problems

    def problems(entry):
        cfg = {**smoke_cfg, "policies": {**smoke_cfg["policies"], "srv": entry}}
        return config_problems(cfg)

    ok = _server(preset="openpi_libero", spec={"max_chunk": 10, "state_dim": 8},
                 keys={"observation/wrist_image": None, "observation/state": {"state": [0, 8], "dtype": "float32"}})
    assert problems(ok) == []
    found = problems(_server(preset="openpi_libro", spec={"max_chunks": 10, "action_dim": 0},
                             keys={"observation/image": {"camera": "head_left", "size": [224], "dtype": "int8"},
                                   "prompt": {"instruction": True, "stream": "task"}}))
    expected = [
        r"policies\.srv\.spec\.max_chunks .* is not a key of policies\.srv\.spec",
        r"policies\.srv\.spec\.action_dim .* must be in \[1, inf\], got 0",
        r"policies\.srv\.preset .* must be one of \['openpi_droid', 'openpi_libero'\], got 'openpi_libro'; did you mean 'openpi_libero'\?",
        r"policies\.srv\.keys\.observation/image\.size .* must be a list of 2 values, got \[224\]",
        r"policies\.srv\.keys\.observation/image\.dtype .* must be one of \['uint8', 'float32', 'float64'\], got 'int8'",
        r"policies\.srv\.keys\.prompt\.stream .* is not a key of policies\.srv\.keys\.prompt",
    ]
    for pattern in expected:
        assert any(re.search(pattern, line) for line in found), (pattern, found)
    assert len(found) == len(expected), found
    # Typed but unfilled: the owner's validator names the key, pointed at the preset.
    (line,) = problems(_server(preset="openpi_droid", spec={"max_chunk": 10}))
    assert line.startswith("policies.srv.preset (") and "'observation/exterior_image_1_left'" in line
