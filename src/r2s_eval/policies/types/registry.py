"""What every policy type shares, and the registry that finds a type by its name.

A policy type (`act`, `pi0`, ...) is one module in this package: a `PolicyType` subclass that
says everything particular to that type (its config defaults, the lerobot config it builds, how
its model is called) and registers itself with `@register`. The rest of r2s-eval asks the
registry (`policy_type(name)`) and never branches on the type string, as LeRobot keeps one
folder per policy type with registered configs.

Nothing here imports torch or lerobot: validating a config (every workflow start) needs only
the defaults (conf/policy_defaults.yaml); the methods that build or call a model import what they need.
"""

from __future__ import annotations

import contextlib

import functools
from collections.abc import Sequence
from typing import Any

from omegaconf import OmegaConf

from r2s_eval.errors import ConfigError, PolicyConfigError
from r2s_eval.paths import CONF_DIR

POLICY_DEFAULTS_FILE = CONF_DIR / "policy_defaults.yaml"


@functools.cache  # the registry and the policy sources read it at import: parse the file once
def read_policy_defaults() -> dict[str, dict[str, Any]]:
    """conf/policy_defaults.yaml, the one owner of every candidate key's default: our top-level keys
    (None = required or derived) for every trained type, the fine-tuned types' recipe over them,
    and the keys of the sources trained elsewhere (checkpoint, server)."""
    values = OmegaConf.to_container(OmegaConf.load(POLICY_DEFAULTS_FILE))
    sections = ["checkpoint", "every_source", "every_type", "fine_tuned", "server"]
    if sorted(values) != sections or not set(values["fine_tuned"]) <= set(values["every_type"]):
        raise ConfigError(f"{POLICY_DEFAULTS_FILE}: must hold {sections}, fine_tuned a subset of every_type's keys")
    return values


_DEFAULTS = read_policy_defaults()
# Every type's keys and defaults; a type's `defaults` replace some of them.
TOP_LEVEL_DEFAULTS: dict[str, Any] = _DEFAULTS["every_type"]
FINE_TUNING_DEFAULTS: dict[str, Any] = _DEFAULTS["fine_tuned"]

# lerobot policy types that do not build offline (yet); named so the error says why.
NOT_SUPPORTED_YET = {
    "pi0_fast": "its model loads the FAST action tokenizer (lerobot/fast-action-tokenizer) as hub remote code",
    "groot": "it builds its Qwen3-VL backbone and processor from hub repositories (remote code)",
}


class PolicyType:
    """A policy type's particulars; the base class is what a LeRobot checkpoint of a type we do not
    train gets when it is loaded (a plain `predict_action_chunk`)."""

    name: str = ""
    fine_tunes = False  # starts from a pretrained checkpoint (`pretrained_path`, `tokenizer_path`)
    defaults: dict[str, Any] = {}  # replace TOP_LEVEL_DEFAULTS' values for this type
    # Keys of the lerobot config that our top-level keys set (an override of one is an error).
    pipeline_keys: tuple[str, ...] = ("chunk_size", "n_action_steps", "device", "input_features", "output_features")
    one_slot_per_call = False  # the model draws its noise from torch's global RNG: one slot per call

    def all_defaults(self) -> dict[str, Any]:
        return {**TOP_LEVEL_DEFAULTS, **self.defaults}

    # -- the lerobot config ----------------------------------------------------------------------
    def lerobot_config(self, cfg: dict):
        """The lerobot config object of the validated `cfg` (features are set from the dataset)."""
        raise PolicyConfigError(f"policy type {self.name!r} cannot be trained here")

    # -- training --------------------------------------------------------------------------------
    def set_training_inputs(self, cfg: dict, lr_cfg, features: dict) -> None:
        """Type-specific changes to the lerobot config once the dataset's features are known."""

    def adapt_preprocessor(self, cfg: dict, preprocessor) -> None:
        """Type-specific steps added to the freshly built preprocessor."""

    def training_speedups(self, policy) -> contextlib.AbstractContextManager:
        """Within it, the model trains faster and computes the same function (up to rounding); the
        weights it leaves are the stock model's, under the stock names."""
        return contextlib.nullcontext()

    # -- inference -------------------------------------------------------------------------------
    def model_chunk_len(self, lr_cfg) -> int:
        """Actions one model call returns."""
        return int(getattr(lr_cfg, "chunk_size", None) or getattr(lr_cfg, "n_action_steps", 1))

    def prepare_loaded_config(self, lr_cfg, tokenizer) -> None:
        """Changes to a checkpoint's config before its model is built (`tokenizer`: local folder)."""

    def prepare_for_batches(self, policy) -> None:
        """Speed-ups of a loaded model that keep what each row gets (fixed-shape batched calls)."""

    def predict(self, runner, slots: Sequence[int | None], observations: list[dict]):
        """One model call for `runner` (a `LeRobotPolicy`); row i belongs to `slots[i]`."""
        return runner.policy.predict_action_chunk(runner.preprocess(observations))

    def checkpoint_state_dict(self, policy, raw: dict) -> dict:
        """`raw` (a model.safetensors) under the names `policy.state_dict()` uses."""
        return dict(raw)


_REGISTRY: dict[str, PolicyType] = {}


def register(cls: type[PolicyType]) -> type[PolicyType]:
    """Class decorator: make `cls` the policy type named `cls.name`."""
    if cls.name in _REGISTRY:
        raise RuntimeError(f"policy type {cls.name!r} registered twice")
    _REGISTRY[cls.name] = cls()
    return cls


def registered() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def policy_type(name: str | None) -> PolicyType:
    """The registered type `name`; a PolicyConfigError naming the supported ones otherwise."""
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name in NOT_SUPPORTED_YET:
        raise PolicyConfigError(
            f"policy type {name!r} is not supported yet: {NOT_SUPPORTED_YET[name]}, "
            f"which does not build offline; supported: {registered()}"
        )
    raise PolicyConfigError(f"policy config 'type' must be one of {registered()}, got {name!r}")


def loaded_type(name: str) -> PolicyType:
    """The type of a loaded checkpoint: its registered type, else the plain base (any LeRobot policy)."""
    return _REGISTRY.get(name) or PolicyType()
