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

The VLA types default to the fine-tuning recipe in `VLA_DEFAULTS` (full fine-tuning, AdamW betas
(0.9, 0.95), cosine 2.5e-5 -> 2.5e-6 after 2000 warm-up steps, EMA 0.9999, batch 32, chunks of 25,
224x224 images of the four cameras); conf/policies/vla.yaml spells the same recipe out.
Relative paths are resolved against the working directory (the project root in the workflow);
they are only checked when training starts, so a line-up composes without the folders.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from collections.abc import Mapping, Sequence
from typing import Any

from r2s_eval.errors import ConfigError

VLA_TYPES = ("pi0", "pi05", "smolvla", "xvla")
SUPPORTED_TYPES = ("act", "diffusion", *VLA_TYPES)
# lerobot policy types that do not build offline (yet); named so the error says why.
NOT_SUPPORTED_YET = {
    "pi0_fast": "its model loads the FAST action tokenizer (lerobot/fast-action-tokenizer) as hub remote code",
    "groot": "it builds its Qwen3-VL backbone and processor from hub repositories (remote code)",
}

# Our top-level keys and their defaults (None = required or derived).
TOP_LEVEL_DEFAULTS: dict[str, Any] = {
    "type": None,  # one of SUPPORTED_TYPES
    "name": None,  # candidate name, informational
    "steps": 300,  # optimiser updates
    "episodes_fraction": 1.0,  # share of each task's demonstrations trained on (data-scale ablations)
    "batch_size": 16,
    "lr": 1e-4,
    "weight_decay": None,  # None: the policy's optimiser preset
    "grad_clip_norm": 10.0,  # lerobot's default
    "warmup_steps": 0,  # linear LR warm-up, then constant (short runs: no cosine decay)
    "threads": 1,  # torch.set_num_threads; training is budgeted per core
    "device": "cpu",  # where training runs: "cpu", "cuda", "cuda:1" (the VLAs want a GPU)
    "log_every": 10,  # steps between logged losses
    "image_keys": ["observation.images.head_left"],
    "image_size": None,  # [H, W]: resize cameras inside the preprocessor; None = native size
    "chunk_size": 25,  # actions predicted per model call
    "overrides": {},
    "pretrained_path": None,  # VLA types: local LeRobot checkpoint folder to fine-tune
    "tokenizer_path": None,  # VLA types: local tokenizer / processor folder (None: local HF cache)
    "scheduler": "constant",  # "constant" | "cosine"
    "decay_lr": None,  # cosine: final learning rate (None: lr / 10)
    "ema_decay": None,  # None: no EMA; else the checkpoint holds the EMA weights
    "betas": None,  # None: the optimiser preset's
    # Trainings per arm with different seeds: the first is the candidate; the others measure the
    # spread of real and sim success that training alone causes (results/fidelity/report.json).
    "seeds": 1,
}

# The fine-tuning recipe (the method's tables for pi0 / pi0.5), the defaults of every VLA type.
VLA_DEFAULTS: dict[str, Any] = {
    "steps": 30_000,
    "batch_size": 32,
    "lr": 2.5e-5,
    "scheduler": "cosine",
    "decay_lr": 2.5e-6,
    "warmup_steps": 2000,
    "betas": [0.9, 0.95],
    "ema_decay": 0.9999,
    "grad_clip_norm": None,  # the preset's: pi0 / pi05 1.0 (openpi), smolvla / xvla 10
    "image_keys": [
        "observation.images.head_left",
        "observation.images.head_right",
        "observation.images.wrist_left",
        "observation.images.wrist_right",
    ],
    "image_size": [224, 224],
    "chunk_size": 25,
}

# Full fine-tuning: every family's freezing switches off (overrides may switch them back on).
FULL_FINETUNING: dict[str, dict[str, Any]] = {
    "pi0": {"freeze_vision_encoder": False, "train_expert_only": False},
    "pi05": {"freeze_vision_encoder": False, "train_expert_only": False},
    "smolvla": {"freeze_vision_encoder": False, "train_expert_only": False, "train_state_proj": True},
    "xvla": {
        "freeze_vision_encoder": False,
        "freeze_language_encoder": False,
        "train_policy_transformer": True,
        "train_soft_prompts": True,
    },
}
# Family defaults under the overrides: X-VLA's "auto" action space takes any action width (its
# other modes assume end-effector layouts with a gripper loss on fixed indices).
VLA_FAMILY_DEFAULTS: dict[str, dict[str, Any]] = {"xvla": {"action_mode": "auto"}}
# Always: the pretrained weights come from `pretrained_path` (loaded by our training loop),
# never from the hub.
VLA_ALWAYS: dict[str, dict[str, Any]] = {"smolvla": {"load_vlm_weights": False}}
# The config field our `image_size` sets, and its order: (H, W) or (W, H).
IMAGE_SIZE_FIELD = {
    "pi0": ("image_resolution", "hw"),
    "pi05": ("image_resolution", "hw"),
    "smolvla": ("resize_imgs_with_padding", "wh"),
    "xvla": ("resize_imgs_with_padding", "hw"),
}
# The tokenizer / processor each family's preprocessor loads by hub id (a config field or fixed).
PALIGEMMA_TOKENIZER = "google/paligemma-3b-pt-224"

# Settings that keep every candidate offline and CPU-sized, whatever the overrides say last.
_ALWAYS = {"pretrained_backbone_weights": None, "push_to_hub": False}


class PolicyConfigError(ConfigError):
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
    policy_type = policy_cfg.get("type")
    if policy_type in NOT_SUPPORTED_YET:
        raise PolicyConfigError(
            f"policy type {policy_type!r} is not supported yet: {NOT_SUPPORTED_YET[policy_type]}, "
            f"which does not build offline; supported: {SUPPORTED_TYPES}"
        )
    if policy_type not in SUPPORTED_TYPES:
        raise PolicyConfigError(f"policy config 'type' must be one of {SUPPORTED_TYPES}, got {policy_type!r}")
    cfg = copy.deepcopy(TOP_LEVEL_DEFAULTS)
    if policy_type in VLA_TYPES:
        cfg.update(copy.deepcopy(VLA_DEFAULTS))
    cfg.update(policy_cfg)
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
    if cfg["type"] in VLA_TYPES:
        if not cfg["pretrained_path"]:
            raise PolicyConfigError(
                f"{where}: type {cfg['type']!r} fine-tunes a pretrained checkpoint; set 'pretrained_path' "
                f"to a local LeRobot checkpoint folder (config.json + model.safetensors)"
            )
    else:
        for key in ("pretrained_path", "tokenizer_path"):
            if cfg[key] is not None:
                raise PolicyConfigError(
                    f"{where}: {key!r} is for the VLA types {VLA_TYPES}; {cfg['type']!r} trains from scratch"
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
    if cfg["grad_clip_norm"] is not None and float(cfg["grad_clip_norm"]) <= 0:
        raise PolicyConfigError(f"{where}: 'grad_clip_norm' must be positive or None, got {cfg['grad_clip_norm']}")


def _config_class(policy_type: str):
    if policy_type == "act":
        from lerobot.policies.act.configuration_act import ACTConfig

        return ACTConfig
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    return DiffusionConfig


def make_lerobot_config(policy_cfg: dict, device: str = "cpu"):
    """Build the lerobot config object (features are filled in later from the dataset)."""
    cfg = validate_policy_cfg(policy_cfg)
    if cfg["type"] in VLA_TYPES:
        return _vla_lerobot_config(cfg, device)
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
                f"override {key!r} is set by the pipeline (top-level 'chunk_size', rollout.horizon, "
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
        # Our runner takes whole chunks from predict_action_chunk; lerobot's n_action_steps only
        # sizes its own select_action queue, which the evaluation never uses: the whole chunk.
        kwargs.update(chunk_size=cfg["chunk_size"], n_action_steps=cfg["chunk_size"])
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


def setting_name(cfg: dict, key: str) -> str:
    """How the user spells `key` of this policy in the Hydra config, for error messages."""
    return f"policies.{cfg.get('name') or cfg['type']}.{key}"


def pretrained_folder(cfg: dict) -> Path:
    """The VLA's pretrained checkpoint folder; raise naming the folder and the setting if unusable."""
    folder = Path(cfg["pretrained_path"]).expanduser()
    missing = [f for f in ("config.json", "model.safetensors") if not (folder / f).is_file()]
    if missing:
        what = "does not exist" if not folder.exists() else f"lacks {' and '.join(missing)}"
        raise PolicyConfigError(
            f"{setting_name(cfg, 'pretrained_path')}: the checkpoint folder {str(folder)!r} {what}; point it at a "
            f"local LeRobot policy checkpoint (config.json + model.safetensors, e.g. lerobot/{cfg['type']}_base "
            f"downloaded beforehand): nothing is downloaded at run time"
        )
    return folder.resolve()


def _vla_lerobot_config(cfg: dict, device: str):
    """The pretrained folder's lerobot config with our recipe, overrides and sizes applied.

    Features are set later from the dataset; `pretrained_path` stays None on the lerobot config
    because our training loop loads the weights itself (partially, see `train.py`).
    """
    from lerobot.configs.policies import PreTrainedConfig

    folder = pretrained_folder(cfg)
    try:
        loaded = PreTrainedConfig.from_pretrained(folder)
    except Exception as exc:  # draccus raises many kinds; all mean "not a config of this lerobot"
        raise PolicyConfigError(
            f"{setting_name(cfg, 'pretrained_path')}: {folder}/config.json is not a LeRobot policy config "
            f"this lerobot version reads: {exc}"
        ) from exc
    if loaded.type != cfg["type"]:
        raise PolicyConfigError(
            f"{setting_name(cfg, 'pretrained_path')}: {folder} holds a {loaded.type!r} policy, "
            f"the config says type {cfg['type']!r}"
        )
    cls = type(loaded)
    field_names = [f.name for f in dataclasses.fields(cls) if f.init]
    overrides = dict(cfg["overrides"])
    unknown = sorted(set(overrides) - set(field_names))
    if unknown:
        raise PolicyConfigError(
            f"unknown override key(s) {unknown} for {cls.__name__} (policy type {cfg['type']!r})"
        )
    image_field = IMAGE_SIZE_FIELD[cfg["type"]][0]
    pipeline_keys = ("chunk_size", "n_action_steps", "device", "input_features", "output_features",
                     "pretrained_path", "tokenizer_name", "vlm_model_name", image_field)
    for key in pipeline_keys:
        if key in overrides:
            raise PolicyConfigError(
                f"override {key!r} is set by the pipeline (top-level 'chunk_size', rollout.horizon, "
                f"'image_size', 'pretrained_path', 'tokenizer_path', the dataset features or the device); remove it"
            )
    kwargs = {name: getattr(loaded, name) for name in field_names}
    kwargs.update(FULL_FINETUNING[cfg["type"]])
    kwargs.update(VLA_FAMILY_DEFAULTS.get(cfg["type"], {}))
    kwargs.update(overrides)
    kwargs.update(VLA_ALWAYS.get(cfg["type"], {}))
    kwargs.update(
        optimizer_lr=cfg["lr"],
        chunk_size=cfg["chunk_size"],
        n_action_steps=cfg["chunk_size"],  # lerobot's own action queue; the evaluation's horizon is ours
        device=device,
        pretrained_path=None,
        push_to_hub=False,
        use_peft=False,
    )
    if cfg["betas"] is not None:
        kwargs["optimizer_betas"] = tuple(cfg["betas"])
    if cfg["weight_decay"] is not None:
        kwargs["optimizer_weight_decay"] = cfg["weight_decay"]
    if cfg["scheduler"] == "cosine":  # recorded in config.json; our loop runs the schedule
        kwargs.update(
            scheduler_warmup_steps=cfg["warmup_steps"],
            scheduler_decay_steps=cfg["steps"],
            scheduler_decay_lr=cosine_floor_lr(cfg),
        )
    if cfg["image_size"] is not None:
        h, w = cfg["image_size"]
        kwargs[image_field] = (h, w) if IMAGE_SIZE_FIELD[cfg["type"]][1] == "hw" else (w, h)
    for key in ("optimizer_betas", "image_resolution", "resize_imgs_with_padding"):
        if isinstance(kwargs.get(key), list):
            kwargs[key] = tuple(kwargs[key])
    try:
        return cls(**kwargs)
    except (TypeError, ValueError, NotImplementedError) as exc:
        raise PolicyConfigError(f"invalid {cls.__name__} settings {overrides}: {exc}") from exc


def cosine_floor_lr(cfg: dict) -> float:
    return float(cfg["decay_lr"]) if cfg["decay_lr"] is not None else float(cfg["lr"]) / 10.0


def tokenizer_hub_name(lerobot_cfg) -> str | None:
    """The hub id of the tokenizer / processor lerobot's preprocessor for this config loads."""
    if lerobot_cfg.type in ("pi0", "pi05"):
        return PALIGEMMA_TOKENIZER  # hard-coded in lerobot's pi0 / pi05 processors
    if lerobot_cfg.type == "smolvla":
        return lerobot_cfg.vlm_model_name
    if lerobot_cfg.type == "xvla":
        return lerobot_cfg.tokenizer_name
    return None


def resolve_tokenizer_path(cfg: dict, lerobot_cfg) -> Path:
    """A local folder with the VLA's tokenizer / processor: `tokenizer_path`, else the hub id's
    snapshot in the local Hugging Face cache. Never touches the network."""
    key = setting_name(cfg, "tokenizer_path")
    hub_name = tokenizer_hub_name(lerobot_cfg)
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


# The candidate line-ups and their budgets live in the Hydra config (conf/policies/*.yaml,
# scaled by conf/experiment/*.yaml): one source of truth for the pipeline and for tests.
CONF_DIR = Path(__file__).resolve().parents[3] / "conf"


def candidate_configs(experiment: str = "demo") -> dict[str, dict]:
    """The validated config of every candidate policy of `experiment`."""
    from r2s_eval.config import compose_config

    from r2s_eval.policies.sources import is_external, validate_source_cfg

    policies = compose_config(CONF_DIR, experiment)["policies"]
    return {
        name: validate_source_cfg(dict(cfg, name=name)) if is_external(cfg) else validate_policy_cfg(dict(cfg, name=name))
        for name, cfg in policies.items()
    }


def candidate_config(name: str, experiment: str = "demo", **changes: Any) -> dict:
    """The config of candidate `name` under `experiment`, with optional top-level changes."""
    candidates = candidate_configs(experiment)
    if name not in candidates:
        raise KeyError(f"unknown candidate policy {name!r}; known: {sorted(candidates)}")
    cfg = copy.deepcopy(candidates[name])
    cfg.update(copy.deepcopy(changes))
    return validate_policy_cfg(cfg)
