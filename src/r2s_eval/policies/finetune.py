"""Fine-tuning a pretrained VLA checkpoint: build for our robot, load what fits, average weights.

The lerobot config comes from the checkpoint's config.json (see `r2s_eval.policies.types.pretrained`); the policy is built
fresh for our features and the pretrained weights are loaded partially (`load_pretrained_partially`):
same name and shape are copied, tensors whose size differs (state / action projections when the
robot is wider than the checkpoint's padding) get the overlapping slice, the rest keep their fresh
initialisation. `EMA` keeps the exponential moving average the checkpoint then holds.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
from pathlib import Path
from typing import Any

import torch

from r2s_eval.policies.checkpoint_files import WEIGHTS_FILE
from r2s_eval.policies.lerobot_policy import checkpoint_state_dict
from r2s_eval.policies.trained_config import resolve_tokenizer_path
from r2s_eval.policies.types import policy_type
from r2s_eval.policies.types.pretrained import pretrained_folder

log = logging.getLogger(__name__)


def build_vla_policy_and_processors(cfg: dict, lr_cfg, meta, stats: dict | None = None):
    """`build_policy_and_processors` for a VLA type, plus the partial-loading report.

    The model is built fresh for our features and the pretrained weights are copied in; the
    processors come from our dataset statistics and the local tokenizer folder.
    """
    from lerobot.policies.factory import make_pre_post_processors

    folder = pretrained_folder(cfg)
    tokenizer = resolve_tokenizer_path(cfg, lr_cfg)
    with _local_tokenizer(lr_cfg, tokenizer):
        policy = policy_type(lr_cfg.type).make_policy(lr_cfg, meta, tokenizer)
        preprocessor, postprocessor = make_pre_post_processors(lr_cfg, dataset_stats=stats or meta.stats)
    report = load_pretrained_partially(policy, folder / WEIGHTS_FILE)
    report.update(pretrained_path=str(folder), tokenizer_path=str(tokenizer))
    return cfg, lr_cfg, policy, preprocessor, postprocessor, report


@contextlib.contextmanager
def _local_tokenizer(lr_cfg, folder: Path):
    """Build the family's processors with the tokenizer read from `folder`.

    lerobot's factories construct `TokenizerProcessorStep(tokenizer_name=<hub id>)`, which loads at
    once; the name the factory module looks up is swapped for a constructor that loads `folder`
    and keeps the hub id as the step's saved `tokenizer_name` (reloads pass the folder again).
    """
    from lerobot.processor import TokenizerProcessorStep

    module = importlib.import_module(type(lr_cfg).__module__.replace("configuration_", "processor_"))
    if getattr(module, "TokenizerProcessorStep", None) is not TokenizerProcessorStep:
        raise RuntimeError(f"{module.__name__} no longer builds a TokenizerProcessorStep: update _local_tokenizer")

    def local_step(*args, tokenizer_name=None, **kwargs):
        step = TokenizerProcessorStep(*args, tokenizer_name=str(folder), **kwargs)
        step.tokenizer_name = tokenizer_name or policy_type(lr_cfg.type).tokenizer_hub_name(lr_cfg)
        return step

    module.TokenizerProcessorStep = local_step
    try:
        yield
    finally:
        module.TokenizerProcessorStep = TokenizerProcessorStep


def load_pretrained_partially(policy, weights_file: str | Path) -> dict[str, Any]:
    """Copy the checkpoint's tensors into `policy` wherever they fit; returns what happened.

    Same name and shape: loaded. Same name, same rank, other sizes: the overlapping slice is
    copied (VLAs pad state and action at the end, so the leading slice is the pretrained part) and
    the rest keeps its fresh initialisation. Not in the checkpoint (or another rank): new.
    """
    from safetensors.torch import load_file

    source = checkpoint_state_dict(policy, load_file(str(weights_file)))
    target = policy.state_dict()
    layouts = _domain_linear_layouts(policy, source)
    loaded, resized, new = [], [], []
    with torch.no_grad():
        for key, dst in target.items():
            src = source.get(key)
            if src is None or src.dim() != dst.dim():
                new.append(key)
            elif src.shape == dst.shape:
                dst.copy_(src)
                loaded.append(key)
            else:
                if key in layouts:
                    layouts[key](dst, src)
                else:
                    overlap = tuple(slice(0, min(a, b)) for a, b in zip(dst.shape, src.shape, strict=True))
                    dst[overlap].copy_(src[overlap])
                resized.append({"name": key, "from": list(src.shape), "to": list(dst.shape)})
    # A tensor tied to a loaded one (stored once in the file) was loaded with it.
    loaded_ptrs = {target[k].data_ptr() for k in loaded}
    tied = [k for k in new if target[k].data_ptr() in loaded_ptrs]
    new = [k for k in new if k not in tied]
    loaded = sorted(loaded + tied)
    unused = sorted(source.keys() - target.keys())
    report = {
        "counts": {"loaded": len(loaded), "resized": len(resized), "new": len(new), "unused": len(unused)},
        "loaded": loaded,
        "resized": resized,
        "new": new,
        "unused": unused,  # in the checkpoint, not in this model
    }
    log.info(
        "pretrained weights from %s: %d tensors loaded, %d resized, %d new (fresh), %d unused",
        weights_file, len(loaded), len(resized), len(new), len(unused),
    )
    for entry in resized:
        log.info("  resized %s: %s -> %s (overlap copied, rest fresh)", entry["name"], entry["from"], entry["to"])
    for key in new:
        log.info("  new %s", key)
    return report


def _domain_linear_layouts(policy, source: dict) -> dict:
    """Resize functions for X-VLA's DomainAwareLinear weights.

    They are stored flat, (domains, in * out), so a plain leading slice would scramble them: they
    are viewed as (domains, in, out). The action encoder's input is [action, proprio, time]; each
    part is copied into its own place.
    """
    funcs = {}
    for name, module in policy.named_modules():
        if type(module).__name__ != "DomainAwareLinear":
            continue
        weight, bias = f"{name}.fc.weight", f"{name}.bias.weight"
        if weight not in source or bias not in source:
            continue
        old_out = int(source[bias].shape[1])
        old_in = int(source[weight].shape[1]) // old_out
        new_in, new_out = int(module.input_size), int(module.output_size)
        segments = [(0, old_in, 0, new_in)]
        decoder_bias = name.replace("action_encoder", "action_decoder") + ".bias.weight"
        if name.endswith("action_encoder") and decoder_bias in source:
            model, dim_time = policy.model, int(policy.config.dim_time)
            old_a = int(source[decoder_bias].shape[1])
            old_p = old_in - old_a - dim_time
            new_a, new_p = int(model.dim_action), int(model.dim_proprio)
            if old_p >= 0 and new_a + new_p + dim_time == new_in:
                segments = [
                    (0, old_a, 0, new_a),
                    (old_a, old_p, new_a, new_p),
                    (old_a + old_p, dim_time, new_a + new_p, dim_time),
                ]

        def resize(dst, src, old=(old_in, old_out), new=(new_in, new_out), segments=segments):
            d = min(dst.shape[0], src.shape[0])
            dst3 = dst.view(dst.shape[0], *new)
            src3 = src.view(src.shape[0], *old)
            out = min(old[1], new[1])
            for old_start, old_len, new_start, new_len in segments:
                n = min(old_len, new_len)
                dst3[:d, new_start : new_start + n, :out].copy_(src3[:d, old_start : old_start + n, :out])

        funcs[weight] = resize
    return funcs


class EMA:
    """Exponential moving average of the trainable weights (openpi's: initialised to the start
    weights, updated after every optimiser step). Kept in float32: with decay 0.9999 a bfloat16
    average would round every update away."""

    def __init__(self, policy, decay: float):
        self.decay = float(decay)
        self.params = [p for p in policy.parameters() if p.requires_grad]
        self.shadow = [p.detach().float().clone() for p in self.params]

    @torch.no_grad()
    def update(self) -> None:
        for avg, p in zip(self.shadow, self.params, strict=True):
            avg.lerp_(p.detach().float(), 1.0 - self.decay)

    @torch.no_grad()
    def copy_to(self) -> None:
        for avg, p in zip(self.shadow, self.params, strict=True):
            p.copy_(avg.to(p.dtype))

    @contextlib.contextmanager
    def applied(self):
        """The average in the model's weights inside the block (a snapshot saves it); the
        optimiser's weights back after it."""
        kept = [p.detach().clone() for p in self.params]
        self.copy_to()
        try:
            yield
        finally:
            with torch.no_grad():
                for saved, p in zip(kept, self.params, strict=True):
                    p.copy_(saved)
