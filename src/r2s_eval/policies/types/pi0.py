"""pi0 (Physical Intelligence's flow-matching VLA on PaliGemma), fine-tuned from a base checkpoint."""

from __future__ import annotations

from r2s_eval.policies.types.registry import register
from r2s_eval.policies.types.pretrained import NoiseArgType

PALIGEMMA_TOKENIZER = "google/paligemma-3b-pt-224"  # hard-coded in lerobot's pi0 / pi05 processors


@register
class Pi0(NoiseArgType):
    name = "pi0"
    full_finetuning = {"freeze_vision_encoder": False, "train_expert_only": False}
    image_size_field = ("image_resolution", "hw")

    def tokenizer_hub_name(self, lr_cfg) -> str | None:
        return PALIGEMMA_TOKENIZER

    def checkpoint_state_dict(self, policy, raw: dict) -> dict:
        # openpi-era checkpoints: the family's own from_pretrained key fixes.
        fixed = policy._fix_pytorch_state_dict_keys(raw, policy.config)
        return {k if k.startswith("model.") else f"model.{k}": v for k, v in fixed.items()}
