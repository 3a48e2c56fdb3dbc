"""Types that fine-tune a pretrained LeRobot checkpoint (the VLA families `pi0`, `pi05`, `smolvla`,
`xvla`): the lerobot config starts from the checkpoint folder's config.json; our recipe, the
candidate's `overrides` and our sizes are applied over it."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from r2s_eval.errors import PolicyConfigError
from r2s_eval.policies.types.registry import FINE_TUNING_DEFAULTS, PolicyType



def setting_name(cfg: dict, key: str) -> str:
    """How the user spells `key` of this policy in the Hydra config, for error messages."""
    return f"policies.{cfg.get('name') or cfg['type']}.{key}"


def pretrained_folder(cfg: dict) -> Path:
    """The pretrained checkpoint folder; raise naming the folder and the setting if unusable."""
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


def cosine_floor_lr(cfg: dict) -> float:
    return float(cfg["decay_lr"]) if cfg["decay_lr"] is not None else float(cfg["lr"]) / 10.0


class FineTunedType(PolicyType):
    fine_tunes = True
    defaults = FINE_TUNING_DEFAULTS  # conf/policy_defaults.yaml, fine_tuned
    full_finetuning: dict[str, Any] = {}  # the family's freezing switches, all off
    family_defaults: dict[str, Any] = {}  # under the overrides
    always: dict[str, Any] = {}  # over the overrides
    image_size_field: tuple[str, str] = ("", "hw")  # the config field `image_size` sets, (H, W) or (W, H)

    def tokenizer_hub_name(self, lr_cfg) -> str | None:
        """The hub id of the tokenizer / processor lerobot's preprocessor for this config loads."""
        return None

    def make_policy(self, lr_cfg, meta, tokenizer: Path):
        """The fresh model for our features (`tokenizer`: the local tokenizer / processor folder)."""
        from lerobot.policies.factory import make_policy

        return make_policy(lr_cfg, ds_meta=meta)

    def set_training_inputs(self, cfg: dict, lr_cfg, features: dict) -> None:
        from lerobot.utils.constants import ACTION, OBS_STATE

        # The VLAs pad state and action to these widths: grow them when the robot is wider.
        lr_cfg.max_state_dim = max(int(lr_cfg.max_state_dim), int(features[OBS_STATE].shape[0]))
        lr_cfg.max_action_dim = max(int(lr_cfg.max_action_dim), int(features[ACTION].shape[0]))

    def lerobot_config(self, cfg: dict):
        """The pretrained folder's lerobot config with our recipe, overrides and sizes applied.

        `pretrained_path` stays None on the lerobot config because our training loop loads the
        weights itself (partially, see `finetune.py`).
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
        image_field, order = self.image_size_field
        pipeline_keys = (*self.pipeline_keys, "pretrained_path", "tokenizer_name", "vlm_model_name", image_field)
        for key in pipeline_keys:
            if key in overrides:
                raise PolicyConfigError(
                    f"override {key!r} is set by the pipeline (top-level 'chunk_size', rollout.horizon, "
                    f"'image_size', 'pretrained_path', 'tokenizer_path', the dataset features or the device); remove it"
                )
        kwargs = {name: getattr(loaded, name) for name in field_names}
        kwargs.update(self.full_finetuning)
        kwargs.update(self.family_defaults)
        kwargs.update(overrides)
        kwargs.update(self.always)
        kwargs.update(
            optimizer_lr=cfg["lr"],
            chunk_size=cfg["chunk_size"],
            n_action_steps=cfg["chunk_size"],  # lerobot's own action queue; the evaluation's horizon is ours
            device=cfg["device"],
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
            kwargs[image_field] = (h, w) if order == "hw" else (w, h)
        for key in ("optimizer_betas", "image_resolution", "resize_imgs_with_padding"):
            if isinstance(kwargs.get(key), list):
                kwargs[key] = tuple(kwargs[key])
        try:
            return cls(**kwargs)
        except (TypeError, ValueError, NotImplementedError) as exc:
            raise PolicyConfigError(f"invalid {cls.__name__} settings {overrides}: {exc}") from exc


class NoiseArgType(FineTunedType):
    """Flow-matching VLAs whose initial noise is given per slot (drawn from the slot's generator)."""

    def predict(self, runner, slots, observations):
        import torch

        cfg = runner.policy.config
        noise = torch.stack([torch.randn((cfg.chunk_size, cfg.max_action_dim), generator=runner.generator(s))
                             for s in slots])
        return runner.policy.predict_action_chunk(runner.preprocess(observations), noise=noise.to(runner.device))
