"""Candidate policy configs: plain dicts validated here, turned into lerobot config classes.

A policy config is a plain (JSON/Hydra-friendly) dict:

    {"type": "act", "steps": 300, "batch_size": 16, "lr": 1e-4,
     "image_keys": ["observation.images.head_left"], "image_size": [64, 64],
     "chunk_size": 25, "n_action_steps": 5, "overrides": {"dim_model": 128}}

Top-level keys are ours (training loop, receding horizon, camera selection); the keys under
`overrides` go verbatim to the lerobot config class (`ACTConfig`, `DiffusionConfig`).
Unknown keys at either level are an error that names the key.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from collections.abc import Mapping, Sequence
from typing import Any

SUPPORTED_TYPES = ("act", "diffusion")

# Our top-level keys and their defaults (None = required or derived).
TOP_LEVEL_DEFAULTS: dict[str, Any] = {
    "type": None,  # "act" | "diffusion"
    "name": None,  # candidate name, informational
    "steps": 300,  # optimiser updates
    "episodes_fraction": 1.0,  # share of each task's demonstrations trained on (data-scale ablations)
    "batch_size": 16,
    "lr": 1e-4,
    "weight_decay": None,  # None: the policy's optimiser preset
    "grad_clip_norm": 10.0,  # lerobot's default
    "warmup_steps": 0,  # linear LR warm-up, then constant (short runs: no cosine decay)
    "threads": 1,  # torch.set_num_threads; training is budgeted per core
    "log_every": 10,  # steps between logged losses
    "image_keys": ["observation.images.head_left"],
    "image_size": None,  # [H, W]: resize cameras inside the preprocessor; None = native size
    "chunk_size": 25,  # actions predicted per model call
    "n_action_steps": 5,  # actions executed before re-querying (receding horizon)
    "overrides": {},
}

# Settings that keep every candidate offline and CPU-sized, whatever the overrides say last.
_ALWAYS = {"pretrained_backbone_weights": None, "push_to_hub": False}


class PolicyConfigError(ValueError):
    """A policy config dict that cannot be turned into a lerobot policy config."""


def _plain(value: Any) -> Any:
    """Deep copy into plain dicts / lists (accepts OmegaConf containers and other mappings)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)) or (isinstance(value, Sequence) and not isinstance(value, str)):
        return [_plain(v) for v in value]
    return copy.deepcopy(value)


def validate_policy_cfg(policy_cfg: Mapping) -> dict:
    """Return a completed copy of `policy_cfg` (defaults filled in); raise on unknown or bad keys."""
    if isinstance(policy_cfg, Mapping):
        policy_cfg = _plain(policy_cfg)
    if not isinstance(policy_cfg, dict):
        raise PolicyConfigError(f"policy config must be a dict, got {type(policy_cfg).__name__}")
    unknown = sorted(set(policy_cfg) - set(TOP_LEVEL_DEFAULTS))
    if unknown:
        raise PolicyConfigError(
            f"unknown policy config key(s) {unknown}; allowed: {sorted(TOP_LEVEL_DEFAULTS)}"
        )
    cfg = copy.deepcopy(TOP_LEVEL_DEFAULTS)
    cfg.update(policy_cfg)
    if cfg["type"] not in SUPPORTED_TYPES:
        raise PolicyConfigError(f"policy config 'type' must be one of {SUPPORTED_TYPES}, got {cfg['type']!r}")
    if not cfg["image_keys"]:
        raise PolicyConfigError("policy config 'image_keys' must list at least one camera")
    if cfg["n_action_steps"] < 1 or cfg["n_action_steps"] > cfg["chunk_size"]:
        raise PolicyConfigError(
            f"policy config needs 1 <= n_action_steps <= chunk_size, got "
            f"n_action_steps={cfg['n_action_steps']} chunk_size={cfg['chunk_size']}"
        )
    if cfg["image_size"] is not None:
        cfg["image_size"] = [int(v) for v in cfg["image_size"]]
        if len(cfg["image_size"]) != 2 or min(cfg["image_size"]) <= 0:
            raise PolicyConfigError(f"policy config 'image_size' must be [H, W], got {cfg['image_size']}")
    if not 0.0 < float(cfg["episodes_fraction"]) <= 1.0:
        raise PolicyConfigError(f"policy config 'episodes_fraction' must be in (0, 1], got {cfg['episodes_fraction']}")
    if not isinstance(cfg["overrides"], dict):
        raise PolicyConfigError("policy config 'overrides' must be a dict")
    return cfg


def _config_class(policy_type: str):
    if policy_type == "act":
        from lerobot.policies.act.configuration_act import ACTConfig

        return ACTConfig
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    return DiffusionConfig


def make_lerobot_config(policy_cfg: dict, device: str = "cpu"):
    """Build the lerobot config object (features are filled in later from the dataset)."""
    cfg = validate_policy_cfg(policy_cfg)
    cls = _config_class(cfg["type"])
    field_names = {f.name for f in dataclasses.fields(cls) if f.init}
    overrides = dict(cfg["overrides"])
    unknown = sorted(set(overrides) - field_names)
    if unknown:
        raise PolicyConfigError(
            f"unknown override key(s) {unknown} for {cls.__name__} (policy type {cfg['type']!r})"
        )
    # Chunking is ours: the model must predict `chunk_size` actions per call.
    for key in ("chunk_size", "horizon", "n_action_steps", "device", "input_features", "output_features"):
        if key in overrides:
            raise PolicyConfigError(
                f"override {key!r} is set by the pipeline (top-level 'chunk_size'/'n_action_steps', "
                f"the dataset features or the device argument); remove it"
            )
    if overrides.get("pretrained_backbone_weights") is not None:
        raise PolicyConfigError(
            "override 'pretrained_backbone_weights' must be None: candidates train from scratch, offline"
        )
    kwargs = {"optimizer_lr": cfg["lr"], **overrides, **_ALWAYS, "device": device}
    # Tuples in lerobot configs arrive as lists from YAML/JSON.
    for key in ("down_dims", "resize_shape", "crop_shape", "optimizer_betas"):
        if key in kwargs and isinstance(kwargs[key], list):
            kwargs[key] = tuple(kwargs[key])
    if cfg["type"] == "act":
        # ACT returns its whole chunk from predict_action_chunk; n_action_steps here only
        # matters to lerobot's own select_action, kept equal to ours for clarity.
        kwargs.update(chunk_size=cfg["chunk_size"], n_action_steps=cfg["n_action_steps"])
        kwargs.setdefault("optimizer_lr_backbone", cfg["lr"])
    else:
        # Diffusion predicts `horizon` steps starting n_obs_steps-1 in the past and its
        # generate_actions keeps `n_action_steps` of them: ask it for the whole chunk.
        n_obs = int(kwargs.get("n_obs_steps", 2))
        n_down = len(kwargs.get("down_dims", (512, 1024, 2048)))
        horizon = _diffusion_horizon(cfg["chunk_size"], n_obs, n_down)
        kwargs.update(horizon=horizon, n_action_steps=cfg["chunk_size"])
        # lerobot's recipe: don't sample the last frames whose windows would be mostly padding.
        kwargs.setdefault("drop_n_last_frames", horizon - cfg["chunk_size"] - n_obs + 1)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError, NotImplementedError) as exc:
        raise PolicyConfigError(f"invalid {cls.__name__} settings {overrides}: {exc}") from exc


def _diffusion_horizon(chunk_size: int, n_obs_steps: int, n_down: int) -> int:
    """Smallest horizon covering the chunk that the UNet can downsample (multiple of 2**n_down)."""
    need = chunk_size + n_obs_steps - 1
    factor = 2**n_down
    return -(-need // factor) * factor


# The candidate line-ups and their budgets live in the Hydra config (conf/policies/*.yaml,
# scaled by conf/experiment/*.yaml): one source of truth for the pipeline and for tests.
CONF_DIR = Path(__file__).resolve().parents[3] / "conf"


def candidate_configs(experiment: str = "demo") -> dict[str, dict]:
    """The validated config of every candidate policy of `experiment`."""
    from r2s_eval.config import compose_config

    policies = compose_config(CONF_DIR, experiment)["policies"]
    return {name: validate_policy_cfg(dict(cfg, name=name)) for name, cfg in policies.items()}


def candidate_config(name: str, experiment: str = "demo", **changes: Any) -> dict:
    """The config of candidate `name` under `experiment`, with optional top-level changes."""
    candidates = candidate_configs(experiment)
    if name not in candidates:
        raise KeyError(f"unknown candidate policy {name!r}; known: {sorted(candidates)}")
    cfg = copy.deepcopy(candidates[name])
    cfg.update(copy.deepcopy(changes))
    return validate_policy_cfg(cfg)
