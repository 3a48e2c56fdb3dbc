"""Candidate policy configs: plain dicts validated here, turned into lerobot config classes.

A policy config is a plain (JSON/Hydra-friendly) dict:

    {"type": "act", "steps": 300, "batch_size": 16, "lr": 1e-4,
     "image_keys": ["observation.images.head_left"], "image_size": [64, 64],
     "chunk_size": 25, "overrides": {"dim_model": 128}}

Top-level keys are ours (training loop, chunk length, camera selection); the keys under
`overrides` go verbatim to the lerobot config class (`ACTConfig`, `DiffusionConfig`, `PI0Config`,
`PI05Config`, `SmolVLAConfig`, `XVLAConfig`). Unknown keys at either level are an error that names
the key. How many of a chunk's actions run before the next query is the evaluation's setting
(`rollout.horizon.execute`), never the policy's: a policy config only says how long a chunk its
model predicts (`chunk_size`).

Types: `act` and `diffusion` train from scratch. The VLA types `pi0`, `pi05`, `smolvla` and `xvla`
fine-tune a pretrained LeRobot checkpoint:

    pretrained_path   local folder of a LeRobot policy checkpoint (config.json + model.safetensors);
                      required for the VLA types, must be None for act / diffusion. The lerobot
                      config starts from that folder's config.json; `overrides` change it.
    tokenizer_path    local folder of the tokenizer / processor the VLA's preprocessor loads
                      (lerobot hard-codes hub ids: pi0 / pi05 `google/paligemma-3b-pt-224`, smolvla
                      its `vlm_model_name`, whose config is also needed to build the model, xvla its
                      `tokenizer_name`). None: that hub id from the local Hugging Face cache, else an
                      error naming this key. Nothing is ever downloaded.

Training-loop keys (all types):

    scheduler         "constant" (linear warm-up over `warmup_steps`, then `lr`) or "cosine"
                      (warm-up, then cosine decay from `lr` to `decay_lr` at the last step)
    decay_lr          final learning rate of the cosine schedule (None: lr / 10)
    ema_decay         exponential moving average of the weights (None: off); the checkpoint then
                      holds the EMA weights
    betas             AdamW/Adam betas (None: the lerobot optimiser preset's)
    grad_clip_norm    None: the preset's value (the VLA default)

Defaults: conf/policy_defaults.yaml, `every_type` for every type; the VLA types default to the
fine-tuning recipe there, `fine_tuned` (full fine-tuning, AdamW betas (0.9, 0.95), cosine 2.5e-5 -> 2.5e-6 after
2000 warm-up steps, EMA 0.9999, batch 32, chunks of 25, 224x224 images of the four cameras). Each
type's particulars live in its module of `r2s_eval.policies.types`; a candidate in conf/policies/
writes only what differs from these defaults.
Relative paths are resolved against the working directory (the project root in the workflow);
they are only checked when training starts, so a line-up composes without the folders.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from r2s_eval.errors import PolicyConfigError
from r2s_eval.policies.types import NOT_SUPPORTED_YET, SUPPORTED_TYPES, TOP_LEVEL_DEFAULTS, policy_type
from r2s_eval.policies.types.pretrained import cosine_floor_lr, pretrained_folder, setting_name

__all__ = ["NOT_SUPPORTED_YET", "SUPPORTED_TYPES", "TOP_LEVEL_DEFAULTS", "PolicyConfigError", "cosine_floor_lr",
           "make_lerobot_config", "pretrained_folder", "resolve_tokenizer_path", "setting_name", "validate_policy_cfg"]


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
    if "n_action_steps" in policy_cfg:
        raise PolicyConfigError(
            "policy config key 'n_action_steps' is not a policy setting: how many actions run before the "
            "next query is the evaluation's receding horizon, rollout.horizon.execute"
        )
    unknown = sorted(set(policy_cfg) - set(TOP_LEVEL_DEFAULTS))
    if unknown:
        raise PolicyConfigError(
            f"unknown policy config key(s) {unknown}; allowed: {sorted(TOP_LEVEL_DEFAULTS)}"
        )
    kind = policy_type(policy_cfg.get("type"))
    cfg = copy.deepcopy(kind.all_defaults())
    # image_keys: null follows the world's first fixed camera in a composed config (r2s_eval.config);
    # read on its own, an entry takes its type's cameras.
    cfg.update({k: v for k, v in policy_cfg.items() if not (k == "image_keys" and v is None)})
    _validate_training_keys(cfg)
    if not cfg["image_keys"]:
        raise PolicyConfigError("policy config 'image_keys' must list at least one camera")
    if int(cfg["chunk_size"]) < 1:
        raise PolicyConfigError(f"policy config 'chunk_size' must be at least 1, got {cfg['chunk_size']}")
    if cfg["image_size"] is not None:
        cfg["image_size"] = [int(v) for v in cfg["image_size"]]
        if len(cfg["image_size"]) != 2 or min(cfg["image_size"]) <= 0:
            raise PolicyConfigError(f"policy config 'image_size' must be [H, W], got {cfg['image_size']}")
    if not 0.0 < float(cfg["episodes_fraction"]) <= 1.0:
        raise PolicyConfigError(f"policy config 'episodes_fraction' must be in (0, 1], got {cfg['episodes_fraction']}")
    if not isinstance(cfg["overrides"], dict):
        raise PolicyConfigError("policy config 'overrides' must be a dict")
    return cfg


def _validate_training_keys(cfg: dict) -> None:
    where = f"policy config {cfg['name']!r}" if cfg.get("name") else "policy config"
    if policy_type(cfg["type"]).fine_tunes:
        if not cfg["pretrained_path"]:
            raise PolicyConfigError(
                f"{where}: type {cfg['type']!r} fine-tunes a pretrained checkpoint; set 'pretrained_path' "
                f"to a local LeRobot checkpoint folder (config.json + model.safetensors)"
            )
    else:
        for key in ("pretrained_path", "tokenizer_path"):
            if cfg[key] is not None:
                raise PolicyConfigError(
                    f"{where}: {key!r} is for the VLA types {_fine_tuned_types()}; {cfg['type']!r} trains from scratch"
                )
    for key in ("pretrained_path", "tokenizer_path"):
        if cfg[key] is not None:
            cfg[key] = str(cfg[key])
    if cfg["scheduler"] not in ("constant", "cosine"):
        raise PolicyConfigError(f"{where}: 'scheduler' must be 'constant' or 'cosine', got {cfg['scheduler']!r}")
    if cfg["decay_lr"] is not None and not 0.0 <= float(cfg["decay_lr"]) <= float(cfg["lr"]):
        raise PolicyConfigError(f"{where}: 'decay_lr' must be in [0, lr={cfg['lr']}], got {cfg['decay_lr']}")
    if cfg["ema_decay"] is not None and not 0.0 < float(cfg["ema_decay"]) < 1.0:
        raise PolicyConfigError(f"{where}: 'ema_decay' must be in (0, 1) or None, got {cfg['ema_decay']}")
    if cfg["betas"] is not None:
        betas = [float(b) for b in cfg["betas"]]
        if len(betas) != 2 or not all(0.0 <= b < 1.0 for b in betas):
            raise PolicyConfigError(f"{where}: 'betas' must be two numbers in [0, 1), got {cfg['betas']}")
        cfg["betas"] = betas
    if isinstance(cfg["seeds"], bool) or not isinstance(cfg["seeds"], int) or cfg["seeds"] < 1:
        raise PolicyConfigError(f"{where}: 'seeds' must be a whole number >= 1, got {cfg['seeds']!r}")
    if cfg["seed"] is not None and (isinstance(cfg["seed"], bool) or not isinstance(cfg["seed"], int) or cfg["seed"] < 0):
        raise PolicyConfigError(f"{where}: 'seed' must be a whole number >= 0 or None, got {cfg['seed']!r}")
    if isinstance(cfg["std_floor"], bool) or not isinstance(cfg["std_floor"], (int, float)) or cfg["std_floor"] < 0:
        raise PolicyConfigError(f"{where}: 'std_floor' must be a number >= 0, got {cfg['std_floor']!r}")
    if cfg["grad_clip_norm"] is not None and float(cfg["grad_clip_norm"]) <= 0:
        raise PolicyConfigError(f"{where}: 'grad_clip_norm' must be positive or None, got {cfg['grad_clip_norm']}")


def _fine_tuned_types() -> tuple[str, ...]:
    return tuple(name for name in SUPPORTED_TYPES if policy_type(name).fine_tunes)


def make_lerobot_config(policy_cfg: dict):
    """Build the lerobot config object on the policy's `device` (features are filled in later from
    the dataset)."""
    cfg = validate_policy_cfg(policy_cfg)
    return policy_type(cfg["type"]).lerobot_config(cfg)


def resolve_tokenizer_path(cfg: dict, lerobot_cfg) -> Path:
    """A local folder with the VLA's tokenizer / processor: `tokenizer_path`, else the hub id's
    snapshot in the local Hugging Face cache. Never touches the network."""
    key = setting_name(cfg, "tokenizer_path")
    hub_name = policy_type(lerobot_cfg.type).tokenizer_hub_name(lerobot_cfg)
    if cfg["tokenizer_path"]:
        folder = Path(cfg["tokenizer_path"]).expanduser()
        if not folder.is_dir():
            raise PolicyConfigError(
                f"{key}: the tokenizer folder {str(folder)!r} does not exist; it must hold the files of "
                f"{hub_name!r} (downloaded beforehand: nothing is downloaded at run time)"
            )
        return folder.resolve()
    if hub_name and Path(hub_name).expanduser().is_dir():  # a config that names a folder already
        return Path(hub_name).expanduser().resolve()
    from huggingface_hub import snapshot_download

    try:
        return Path(snapshot_download(hub_name, local_files_only=True))
    except Exception as exc:  # not cached (LocalEntryNotFoundError), or an invalid id
        raise PolicyConfigError(
            f"{key} is not set and {hub_name!r}, the tokenizer/processor lerobot's {lerobot_cfg.type} "
            f"preprocessor loads, is not in the local Hugging Face cache; download it beforehand and set "
            f"{key} to its folder (nothing is downloaded at run time)"
        ) from exc
