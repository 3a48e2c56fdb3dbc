"""SmolVLA, fine-tuned from a base checkpoint; it builds its VLM from `vlm_model_name`'s config."""

from __future__ import annotations

from pathlib import Path

from r2s_eval.policies.types.registry import register
from r2s_eval.policies.types.pretrained import NoiseArgType


@register
class SmolVLA(NoiseArgType):
    name = "smolvla"
    full_finetuning = {"freeze_vision_encoder": False, "train_expert_only": False, "train_state_proj": True}
    # The pretrained weights come from `pretrained_path` (loaded by our training loop), never the hub.
    always = {"load_vlm_weights": False}
    image_size_field = ("resize_imgs_with_padding", "wh")

    def tokenizer_hub_name(self, lr_cfg) -> str | None:
        return lr_cfg.vlm_model_name

    def make_policy(self, lr_cfg, meta, tokenizer: Path):
        from lerobot.policies.factory import make_policy

        # SmolVLA builds its VLM from the config and processor of `vlm_model_name`.
        hub_name, lr_cfg.vlm_model_name = lr_cfg.vlm_model_name, str(tokenizer)
        try:
            return make_policy(lr_cfg, ds_meta=meta)
        finally:
            lr_cfg.vlm_model_name = hub_name  # the saved config names the hub id, like the base

    def prepare_loaded_config(self, lr_cfg, tokenizer) -> None:
        lr_cfg.load_vlm_weights = False  # every weight is in the checkpoint
        if tokenizer is not None:
            lr_cfg.vlm_model_name = str(tokenizer)  # the VLM is built from that folder's config
