"""Tiny, randomly initialised SmolVLA checkpoints, built offline through LeRobot's own classes.

SmolVLA builds its VLM from ``AutoConfig`` / ``AutoProcessor`` of ``vlm_model_name`` (weights only
with ``load_vlm_weights=True``), so a local folder holding a tiny SmolVLM config and processor is
enough: no download, no size substitution. A checkpoint made here (config, weights, pre- and
post-processor with synthetic statistics) loads through the same code as a lab's checkpoint
(``r2s_eval.policies.lerobot_policy.load_lerobot_policy``). Its actions mean nothing: it exists so
that smoke experiments and tests drive a real VLA code path on a CPU in seconds.

    python -m r2s_eval.policies.tiny OUT --cameras observation.images.image observation.images.wrist_image \
        --state-dim 8 --action-dim 7 --chunk-size 25 [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from r2s_eval.policies.interface import STATE_KEY

ACTION_KEY = "action"
CAMERAS = ("observation.images.head_left", "observation.images.wrist_left")
TASK = "pick up the red cube and put it in the bowl"

_TOKENIZER_CORPUS = (
    TASK,
    "fold the towel and place it on the table",
    "open the drawer then close it again",
    "Task: stack the blocks, State: 0 12 127 128 200 255;\nAction: ",
    # pi0.5 spells the state as bin numbers 0..255.
    " ".join(str(i) for i in range(256)),
)


def policy_features(cameras: Sequence[str], image_hw: tuple[int, int], state_dim: int, action_dim: int) -> dict:
    """`input_features` / `output_features` of a policy config: the cameras, the state, the action."""
    from lerobot.configs import FeatureType, PolicyFeature

    return {
        "input_features": {
            **{cam: PolicyFeature(type=FeatureType.VISUAL, shape=(3, *image_hw)) for cam in cameras},
            STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(state_dim,)),
        },
        "output_features": {ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))},
    }


SMOLVLM_HUB_NAME = "HuggingFaceTB/SmolVLM2-500M-Video-Instruct"

_BPE_CORPUS = _TOKENIZER_CORPUS[:4] + (
    "pick the cube",
    "put the cup on the plate",
    "stack the two blocks",
    "cover the ball with the cup",
)


@dataclass(frozen=True)
class SmolDims:
    """A SmolVLM with a 2-layer llama text model (width 64) and a 1-layer SigLIP-like vision tower on
    64x64 images (16x16 patches, pixel-shuffle factor 2: 4 image tokens)."""

    text_width: int = 64
    text_mlp: int = 128
    text_depth: int = 2
    text_heads: int = 4
    text_kv_heads: int = 2
    text_head_dim: int = 16
    vocab_size: int = 320
    vision_width: int = 32
    vision_mlp: int = 64
    vision_depth: int = 1
    vision_heads: int = 2
    image_size: int = 64
    patch_size: int = 16
    scale_factor: int = 2


def build_bpe_tokenizer(
    vocab_size: int,
    special_tokens: Sequence[str],
    *,
    wrap_with: tuple[str, str] | None = None,
    **named_tokens: Any,
):
    """A byte-level BPE tokenizer (~``vocab_size`` tokens) trained on a few sentences, as a
    ``PreTrainedTokenizerFast``. ``wrap_with=(bos, eos)`` adds them around every sequence (BART
    style); ``named_tokens`` are the tokenizer's named special tokens (``bos_token=...``,
    ``extra_special_tokens={...}``)."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, processors, trainers
    from transformers import PreTrainedTokenizerFast

    bpe = Tokenizer(models.BPE(unk_token="<unk>"))
    bpe.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    bpe.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=vocab_size,
        special_tokens=list(special_tokens),
        show_progress=False,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
    )
    bpe.train_from_iterator(list(_BPE_CORPUS) * 4, trainer)
    if wrap_with is not None:
        bos, eos = wrap_with
        bpe.post_processor = processors.TemplateProcessing(
            single=f"{bos} $A {eos}",
            special_tokens=[(bos, bpe.token_to_id(bos)), (eos, bpe.token_to_id(eos))],
        )
    return PreTrainedTokenizerFast(tokenizer_object=bpe, **named_tokens)


def build_tiny_smolvlm(folder: Path, dims: SmolDims = SmolDims()) -> Path:
    """A folder that ``AutoConfig`` and ``AutoProcessor`` read as a tiny SmolVLM (no weights file):
    what SmolVLA's ``vlm_model_name`` must point at when ``load_vlm_weights=False``."""
    from transformers import SmolVLMConfig, SmolVLMImageProcessor, SmolVLMProcessor, SmolVLMVideoProcessor

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    image_tokens = {
        "fake_image_token": "<fake_token_around_image>",
        "global_image_token": "<global-img>",
        "image_token": "<image>",
        "end_of_utterance_token": "<end_of_utterance>",
        "video_token": "<video>",
    }
    tokenizer = build_bpe_tokenizer(
        dims.vocab_size - 20,
        ["<|endoftext|>", "<unk>", "<pad>", *image_tokens.values()],
        bos_token="<|endoftext|>",
        eos_token="<end_of_utterance>",
        unk_token="<unk>",
        pad_token="<pad>",
        # SmolVLA reads `tokenizer.fake_image_token_id` / `global_image_token_id`.
        extra_special_tokens=image_tokens,
    )
    if len(tokenizer) > dims.vocab_size:
        raise AssertionError(f"tokenizer has {len(tokenizer)} tokens > vocab_size {dims.vocab_size}")
    config = SmolVLMConfig(
        text_config={
            "model_type": "llama",
            "hidden_size": dims.text_width,
            "intermediate_size": dims.text_mlp,
            "num_hidden_layers": dims.text_depth,
            "num_attention_heads": dims.text_heads,
            "num_key_value_heads": dims.text_kv_heads,
            "head_dim": dims.text_head_dim,
            "vocab_size": dims.vocab_size,
            "max_position_embeddings": 512,
            "pad_token_id": tokenizer.pad_token_id,
        },
        vision_config={
            "hidden_size": dims.vision_width,
            "intermediate_size": dims.vision_mlp,
            "num_hidden_layers": dims.vision_depth,
            "num_attention_heads": dims.vision_heads,
            "image_size": dims.image_size,
            "patch_size": dims.patch_size,
        },
        scale_factor=dims.scale_factor,
        image_token_id=tokenizer.convert_tokens_to_ids("<image>"),
        pad_token_id=tokenizer.pad_token_id,
    )
    config.save_pretrained(folder)
    size = {"longest_edge": dims.image_size}
    processor = SmolVLMProcessor(
        image_processor=SmolVLMImageProcessor(size=size, max_image_size=size, do_image_splitting=False),
        tokenizer=tokenizer,
        video_processor=SmolVLMVideoProcessor(size=size, max_image_size=size),
        image_seq_len=((dims.image_size // dims.patch_size) // dims.scale_factor) ** 2,
    )
    processor.save_pretrained(folder)
    return folder


def tiny_smolvla_config(
    vlm_dir: Path,
    *,
    state_dim: int = 14,
    action_dim: int = 14,
    cameras: Sequence[str] = CAMERAS,
    image_hw: tuple[int, int] = (64, 64),
    **overrides: Any,
):
    from lerobot.policies.smolvla import SmolVLAConfig

    kwargs: dict[str, Any] = dict(
        vlm_model_name=str(vlm_dir),
        load_vlm_weights=False,
        num_vlm_layers=2,
        resize_imgs_with_padding=(image_hw[1], image_hw[0]),  # SmolVLA stores (width, height)
        tokenizer_max_length=16,
        num_steps=2,
        # LeRobot's own fields of the test model (callers override them); the evaluation's
        # receding horizon is rollout.horizon, never these.
        chunk_size=10,
        n_action_steps=5,
        max_state_dim=max(32, state_dim),
        max_action_dim=max(32, action_dim),
        device="cpu",
        push_to_hub=False,
        **policy_features(cameras, image_hw, state_dim, action_dim),
    )
    kwargs.update(overrides)
    return SmolVLAConfig(**kwargs)


def build_tiny_smolvla(
    folder: Path,
    vlm_dir: Path,
    *,
    seed: int = 0,
    hub_name: str | None = SMOLVLM_HUB_NAME,
    **config_kwargs: Any,
) -> Path:
    """Save a freshly initialised tiny SmolVLA (config.json + model.safetensors) into ``folder``.

    The VLM is built from ``vlm_dir`` (see ``build_tiny_smolvlm``); the saved config names
    ``hub_name`` instead, like ``lerobot/smolvla_base``, unless ``hub_name`` is None."""
    from lerobot.policies.factory import get_policy_class

    config = tiny_smolvla_config(vlm_dir, **config_kwargs)
    torch.manual_seed(seed)
    policy = get_policy_class("smolvla")(config)
    if hub_name is not None:
        policy.config.vlm_model_name = hub_name
    policy.save_pretrained(Path(folder))
    return Path(folder)




def synthetic_stats(state_dim: int, action_dim: int, seed: int = 0) -> dict[str, dict[str, torch.Tensor]]:
    """Normalisation statistics of made-up unit-scale data, every key a normaliser reads."""
    gen = torch.Generator().manual_seed(seed)
    stats = {}
    for key, dim in ((STATE_KEY, state_dim), (ACTION_KEY, action_dim)):
        centre, half = torch.rand(dim, generator=gen) - 0.5, 0.5 + torch.rand(dim, generator=gen)
        stats[key] = {"mean": centre, "std": half / 3**0.5, "min": centre - half, "max": centre + half,
                      "q01": centre - 0.98 * half, "q99": centre + 0.98 * half}
    return stats


def build_tiny_checkpoint(folder: Path, *, cameras: Sequence[str], state_dim: int, action_dim: int,
                          chunk_size: int, seed: int = 0, image_hw: tuple[int, int] = (64, 64)) -> Path:
    """A self-contained tiny SmolVLA checkpoint in ``folder``: ``vlm/`` (its tiny SmolVLM config
    and tokenizer) and ``pretrained_model/`` (config, weights, processors); returns the latter.
    ``chunk_size``: actions the model predicts per call (the workflow gives rollout.horizon.chunk)."""
    from lerobot.policies.factory import make_pre_post_processors

    folder = Path(folder).absolute()
    vlm = build_tiny_smolvlm(folder / "vlm")
    ckpt = build_tiny_smolvla(folder / "pretrained_model", vlm, seed=seed, hub_name=None, cameras=tuple(cameras),
                              state_dim=state_dim, action_dim=action_dim, image_hw=tuple(image_hw),
                              # LeRobot's own action queue is unused (RecedingHorizon owns re-planning).
                              chunk_size=chunk_size, n_action_steps=chunk_size)
    from lerobot.configs.policies import PreTrainedConfig

    config = PreTrainedConfig.from_pretrained(ckpt)
    pre, post = make_pre_post_processors(config, dataset_stats=synthetic_stats(state_dim, action_dim, seed))
    pre.save_pretrained(ckpt)
    post.save_pretrained(ckpt)
    return ckpt


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m r2s_eval.policies.tiny", description=__doc__.split("\n\n")[0])
    p.add_argument("out", help="folder to create (vlm/ and pretrained_model/ inside)")
    p.add_argument("--cameras", nargs="+", required=True, help="observation keys of its cameras")
    p.add_argument("--state-dim", type=int, required=True)
    p.add_argument("--action-dim", type=int, required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--chunk-size", type=int, required=True, help="actions the model predicts per call")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    ckpt = build_tiny_checkpoint(Path(args.out), cameras=args.cameras, state_dim=args.state_dim,
                                 action_dim=args.action_dim, seed=args.seed, chunk_size=args.chunk_size)
    print(json.dumps({"checkpoint": str(ckpt)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
