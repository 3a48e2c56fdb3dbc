"""The policy-type registry: every trained type is one registered module, found by name."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from r2s_eval.errors import ConfigError, PolicyConfigError
from r2s_eval.policies.trained_config import validate_policy_cfg
from r2s_eval.policies.types import SUPPORTED_TYPES, TOP_LEVEL_DEFAULTS, PolicyType, loaded_type, policy_type
from r2s_eval.policies.types.pretrained import FINE_TUNING_DEFAULTS

POLICIES = Path(__file__).resolve().parents[2] / "src" / "r2s_eval" / "policies"


def test_every_supported_type_is_registered_with_its_own_module():
    assert set(SUPPORTED_TYPES) == {"act", "diffusion", "pi0", "pi05", "smolvla", "xvla"}
    for name in SUPPORTED_TYPES:
        kind = policy_type(name)
        assert kind.name == name
        assert type(kind).__module__ == f"r2s_eval.policies.types.{name}"


def test_an_unknown_type_is_a_config_error_naming_the_supported_ones():
    with pytest.raises(PolicyConfigError, match="must be one of") as err:
        policy_type("transformer_xl")
    assert isinstance(err.value, ConfigError) and "act" in str(err.value)
    with pytest.raises(PolicyConfigError, match="not supported yet"):
        validate_policy_cfg({"type": "groot"})


def test_a_checkpoint_of_a_type_not_trained_here_loads_as_the_plain_base():
    assert type(loaded_type("some_new_lerobot_policy")) is PolicyType
    assert loaded_type("xvla").one_slot_per_call and not loaded_type("pi0").one_slot_per_call


def test_defaults_come_from_the_type():
    assert validate_policy_cfg({"type": "act"})["batch_size"] == TOP_LEVEL_DEFAULTS["batch_size"]
    vla = validate_policy_cfg({"type": "pi0", "pretrained_path": "somewhere"})
    assert {k: vla[k] for k in FINE_TUNING_DEFAULTS} == FINE_TUNING_DEFAULTS
    assert policy_type("pi0").fine_tunes and not policy_type("act").fine_tunes


def test_no_module_outside_the_registry_branches_on_a_type_name():
    # A new type touches policies/types/ only: no other policies module compares with a type name.
    names = set(SUPPORTED_TYPES)
    for path in POLICIES.glob("*.py"):
        if path.name == "tiny.py":  # builds a SmolVLA checkpoint on purpose, by its config class
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                consts = [c.value for c in ast.walk(node) if isinstance(c, ast.Constant)]
                assert not names & set(consts), f"{path.name}:{node.lineno} branches on a policy type"
