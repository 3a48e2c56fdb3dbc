"""Backend "transformers": a local VLM through AutoProcessor and the matching auto model class.

The model is loaded once, on first use, with ``from_pretrained`` from ``model`` (a checkpoint
folder or hub id), and generates greedily on ``device`` in ``dtype``. ``family`` picks how the
checkpoint is loaded:

* ``qwen3_vl``, ``qwen2_5_vl``, ``qwen2_vl``, ``gemma3``: ``AutoModelForImageTextToText``;
* ``llava_ov_1_5`` (LLaVA-OneVision-1.5): ``AutoModelForCausalLM`` with the checkpoint's own code
  (``trust_remote_code``).

Video frames go in as a sequence of images, which every family's chat template accepts.
"""

from __future__ import annotations

import threading
from typing import Any

from r2s_eval.errors import ConfigError, JudgeError
from r2s_eval.judge.base import register_judge
from r2s_eval.judge.clip_frames import Clip, pil_frames
from r2s_eval.judge.vlm import COMMON_DEFAULTS, Reply, VLMJudge

FAMILIES: dict[str, dict[str, Any]] = {
    "qwen3_vl": {"auto_class": "AutoModelForImageTextToText", "trust_remote_code": False},
    "qwen2_5_vl": {"auto_class": "AutoModelForImageTextToText", "trust_remote_code": False},
    "qwen2_vl": {"auto_class": "AutoModelForImageTextToText", "trust_remote_code": False},
    "gemma3": {"auto_class": "AutoModelForImageTextToText", "trust_remote_code": False},
    "llava_ov_1_5": {"auto_class": "AutoModelForCausalLM", "trust_remote_code": True},
}


@register_judge("transformers")
class TransformersJudge(VLMJudge):
    DEFAULTS = {
        **COMMON_DEFAULTS,
        "backend": "transformers",
        "family": "qwen3_vl",
        "device": "cpu",  # "cpu", "cuda", "cuda:1", ...
        "dtype": "auto",  # "auto", "float32", "bfloat16", "float16"
        "revision": None,
        "trust_remote_code": None,  # None: the family's default
        "local_files_only": False,
        "attn_implementation": None,
    }
    TRANSPORT_KEYS = frozenset({"name", "device", "local_files_only", "attn_implementation"})

    def __init__(self, cfg=None):
        super().__init__(cfg)
        if self.cfg["family"] not in FAMILIES:
            raise ConfigError(f"transformers judge: unknown family {self.cfg['family']!r}; known: {sorted(FAMILIES)}")
        self._model = self._processor = None
        self._lock = threading.Lock()  # one generate at a time on one model

    def _load(self) -> None:
        import torch
        import transformers

        c, fam = self.cfg, FAMILIES[self.cfg["family"]]
        trust = fam["trust_remote_code"] if c["trust_remote_code"] is None else bool(c["trust_remote_code"])
        common = {"revision": c["revision"], "trust_remote_code": trust, "local_files_only": bool(c["local_files_only"])}
        dtype = c["dtype"] if c["dtype"] == "auto" else getattr(torch, str(c["dtype"]))
        extra = {"attn_implementation": c["attn_implementation"]} if c["attn_implementation"] else {}
        try:
            self._processor = transformers.AutoProcessor.from_pretrained(c["model"], **common)
            auto = getattr(transformers, fam["auto_class"])
            model = auto.from_pretrained(c["model"], dtype=dtype, **common, **extra)
        except (OSError, ValueError) as e:
            raise JudgeError(f"judge {self.name!r}: cannot load {c['family']} model from {c['model']}: {e}") from e
        self._model = model.to(c["device"]).eval()

    def _conversation(self, messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
        conv = []
        for m in messages:
            parts = []
            for p in m["content"]:
                if isinstance(p, Clip):
                    parts += [{"type": "image", "image": im} for im in pil_frames(p)]
                else:
                    parts.append({"type": "text", "text": p})
            conv.append({"role": m["role"], "content": parts})
        return conv

    def _generate(self, messages: list[dict[str, Any]]) -> Reply:
        import torch

        with self._lock:
            if self._model is None:
                self._load()
            model, proc = self._model, self._processor
            inputs = proc.apply_chat_template(
                self._conversation(messages), add_generation_prompt=True, tokenize=True,
                return_dict=True, return_tensors="pt",
            )
            inputs = {
                k: (v.to(model.device, dtype=model.dtype) if v.is_floating_point() else v.to(model.device))
                for k, v in inputs.items() if isinstance(v, torch.Tensor)
            }
            n_in = int(inputs["input_ids"].shape[1])
            with torch.inference_mode():
                # Greedy: sampling settings in the checkpoint's generation config are switched off.
                out = model.generate(
                    **inputs, do_sample=False, max_new_tokens=int(self.cfg["max_new_tokens"]),
                    temperature=None, top_p=None, top_k=None,
                )
            new = out[0, n_in:]
            text = proc.decode(new, skip_special_tokens=True)
        return Reply(text=text, tokens_in=n_in, tokens_out=int(new.shape[0]))
