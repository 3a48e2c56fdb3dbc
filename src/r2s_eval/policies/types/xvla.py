"""X-VLA, fine-tuned from a base checkpoint; it draws its noise from torch's global RNG."""

from __future__ import annotations

from r2s_eval.policies.types.registry import register
from r2s_eval.policies.types.pretrained import FineTunedType


@register
class XVLA(FineTunedType):
    name = "xvla"
    full_finetuning = {
        "freeze_vision_encoder": False,
        "freeze_language_encoder": False,
        "train_policy_transformer": True,
        "train_soft_prompts": True,
    }
    # "auto" takes any action width (the other modes assume end-effector layouts with a gripper
    # loss on fixed indices).
    family_defaults = {"action_mode": "auto"}
    image_size_field = ("resize_imgs_with_padding", "hw")
    one_slot_per_call = True  # the draw must be the slot's alone

    def tokenizer_hub_name(self, lr_cfg) -> str | None:
        return lr_cfg.tokenizer_name

    def predict(self, runner, slots, observations):
        import torch

        # Called one slot at a time with torch's global RNG seeded from the slot's generator.
        seed = int(torch.randint(0, 2**31 - 1, (1,), generator=runner.generator(slots[0])))
        devices = [runner.device] if runner.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(seed)
            return runner.policy.predict_action_chunk(runner.preprocess(observations))

    def checkpoint_state_dict(self, policy, raw: dict) -> dict:
        from lerobot.policies.xvla import modeling_xvla

        # The vendored Florence-2 layout, and tied embeddings that safetensors stores once.
        if modeling_xvla._is_vendored_florence_state_dict(raw):
            raw = modeling_xvla._remap_vendored_florence_state_dict(raw)
        raw = dict(raw)
        shared, embed = "model.vlm.language_model.shared.weight", "model.vlm.language_model.encoder.embed_tokens.weight"
        if shared in raw and embed not in raw:
            raw[embed] = raw[shared]
        elif embed in raw and shared not in raw:
            raw[shared] = raw[embed]
        return raw
