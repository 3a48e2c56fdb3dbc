"""Tiny, randomly initialised pi0 / pi0.5 policies built through lerobot's own classes, fully offline.

Why a substitution is needed: lerobot 0.6.1's ``PI0Config`` / ``PI05Config`` accept only the
``gemma_2b`` / ``gemma_300m`` variants, and ``PaliGemmaWithExpertModel`` hard-codes a 257152-token
vocabulary, a 27-layer SigLIP tower and a 2048-wide projector, so the smallest model those configs
can describe has about four billion parameters. No config field can make it small. We therefore swap,
for the duration of a context, three module-level names that ``lerobot.policies.pi0.modeling_pi0`` and
``lerobot.policies.pi05.modeling_pi05`` look up when they build the network:

* ``get_gemma_config``: the per-variant widths of the VLM and the action expert;
* ``PaliGemmaForConditionalGenerationWithPiGemma``: shrinks the vocabulary and the vision tower on the
  config lerobot built, then builds the real class;
* ``PiGemmaForCausalLM``: shrinks the vocabulary of the action expert, then builds the real class.

Everything else (policy, flow-matching model, attention masks, processors, save / load) is lerobot's
unchanged code, so a test exercises the real API. The substitution only changes sizes: the swap must be
active whenever such a policy is *built*, including ``from_pretrained`` (which first builds the model and
then loads the weights).

Both processors hard-code the ``google/paligemma-3b-pt-224`` tokenizer. ``tiny_pi_env`` serves a small BPE
tokenizer, trained here on a few sentences, under that name from a private Hugging Face cache in a temporary
folder, with the hub switched to offline mode and non-loopback sockets refused.

Typical use::

    with tiny_pi_env(tmp_path / "hf") as env:
        folder = build_tiny_pi("pi0", tmp_path / "pi0")
        policy, pre, post = load_tiny_pi(folder)
        assert not env.network_attempts
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from unittest import mock

import torch

from r2s_eval.policies.tiny import (  # the SmolVLA builders live in the package (smoke runs use them)
    _TOKENIZER_CORPUS,
    ACTION_KEY,
    CAMERAS,
    SMOLVLM_HUB_NAME,
    STATE_KEY,
    TASK,
    SmolDims,
    build_bpe_tokenizer,
    build_tiny_smolvla,
    build_tiny_smolvlm,
    policy_features,
    tiny_smolvla_config,
)

PALIGEMMA_TOKENIZER = "google/paligemma-3b-pt-224"
# Any fixed 40-hex string works: the hub cache resolves `refs/main` to this snapshot folder.
_SNAPSHOT = "7e1e5e7e00000000000000000000000000000000"



@dataclass(frozen=True)
class TinyDims:
    """Sizes of the tiny networks. The VLM and the expert share depth, heads, kv-heads and head_dim
    because lerobot runs their layers side by side in one joint attention."""

    vlm_width: int = 64
    vlm_mlp: int = 128
    expert_width: int = 32
    expert_mlp: int = 64
    depth: int = 2
    # lerobot reshapes the joint attention output as `8 * head_dim`, so 8 query heads are mandatory.
    num_heads: int = 8
    num_kv_heads: int = 1
    head_dim: int = 8
    vocab_size: int = 512
    vision_width: int = 32
    vision_mlp: int = 64
    vision_depth: int = 1
    vision_heads: int = 2
    patch_size: int = 16


DEFAULT_DIMS = TinyDims()


# ----------------------------------------------------------------------------------------------
# Size substitution
# ----------------------------------------------------------------------------------------------


def _pi_modeling_modules() -> list[Any]:
    from lerobot.policies.pi0 import modeling_pi0
    from lerobot.policies.pi05 import modeling_pi05

    return [modeling_pi0, modeling_pi05]


def _tiny_substitutes(module: Any, dims: TinyDims) -> dict[str, Any]:
    from lerobot.policies import pi_gemma

    real_vlm = pi_gemma.PaliGemmaForConditionalGenerationWithPiGemma
    real_expert = pi_gemma.PiGemmaForCausalLM

    def get_gemma_config(variant: str):
        # Keep both variant names meaningful: the "2b" VLM stays wider than the "300m" expert.
        if variant == "gemma_2b":
            width, mlp = dims.vlm_width, dims.vlm_mlp
        elif variant == "gemma_300m":
            width, mlp = dims.expert_width, dims.expert_mlp
        else:
            raise ValueError(f"Unknown variant: {variant}")
        return module.GemmaConfig(
            width=width,
            depth=dims.depth,
            mlp_dim=mlp,
            num_heads=dims.num_heads,
            num_kv_heads=dims.num_kv_heads,
            head_dim=dims.head_dim,
        )

    def paligemma(config):
        # lerobot overwrote these on a default PaliGemmaConfig just before this call.
        config.vocab_size = dims.vocab_size
        config.image_token_index = dims.vocab_size
        config.text_config.vocab_size = dims.vocab_size
        vision = config.vision_config
        vision.hidden_size = dims.vision_width
        vision.intermediate_size = dims.vision_mlp
        vision.num_hidden_layers = dims.vision_depth
        vision.num_attention_heads = dims.vision_heads
        vision.patch_size = dims.patch_size
        # The projector maps SigLIP features straight into the VLM's token width.
        vision.projection_dim = config.text_config.hidden_size
        config.projection_dim = config.hidden_size = config.text_config.hidden_size
        config.text_config.num_image_tokens = (vision.image_size // vision.patch_size) ** 2
        return real_vlm(config=config)

    def expert(config, **kwargs):
        config.vocab_size = dims.vocab_size
        return real_expert(config=config, **kwargs)

    return {
        "get_gemma_config": get_gemma_config,
        "PaliGemmaForConditionalGenerationWithPiGemma": paligemma,
        "PiGemmaForCausalLM": expert,
    }


@contextlib.contextmanager
def tiny_pi_models(dims: TinyDims = DEFAULT_DIMS) -> Iterator[TinyDims]:
    """Make pi0 / pi0.5 policies built inside this context tiny (see the module docstring)."""
    with contextlib.ExitStack() as stack:
        for module in _pi_modeling_modules():
            for name, value in _tiny_substitutes(module, dims).items():
                if not hasattr(module, name):
                    raise AttributeError(f"{module.__name__}.{name} is gone: update the tiny substitution")
                stack.enter_context(mock.patch.object(module, name, value))
        yield dims


# ----------------------------------------------------------------------------------------------
# Offline hub with a private tokenizer cache
# ----------------------------------------------------------------------------------------------


def build_tiny_tokenizer(vocab_size: int = DEFAULT_DIMS.vocab_size):
    """A Gemma-style BPE tokenizer (byte fallback, '▁' for spaces, <bos> prepended) trained on a few
    sentences. Its ids stay below ``vocab_size`` so they index the tiny embedding table."""
    from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, trainers
    from transformers import GemmaTokenizer

    # Same special-token ids as PaliGemma's tokenizer; the byte tokens make any text encodable.
    specials = ["<pad>", "<eos>", "<bos>", "<unk>", "<mask>"] + [f"<0x{i:02X}>" for i in range(256)]
    if vocab_size <= len(specials):
        raise ValueError(f"vocab_size must exceed {len(specials)} (special and byte tokens)")
    bpe = Tokenizer(models.BPE(unk_token="<unk>", byte_fallback=True, fuse_unk=True))
    bpe.normalizer = normalizers.Replace(" ", "▁")
    bpe.pre_tokenizer = pre_tokenizers.Split(pattern="▁", behavior="merged_with_previous")
    trainer = trainers.BpeTrainer(vocab_size=vocab_size, special_tokens=specials, show_progress=False)
    bpe.train_from_iterator(list(_TOKENIZER_CORPUS) * 4, trainer)
    model = json.loads(bpe.to_str())["model"]
    merges = [tuple(m) if isinstance(m, list) else tuple(m.split(" ")) for m in model["merges"]]
    tokenizer = GemmaTokenizer(vocab=model["vocab"], merges=merges, add_bos_token=True)
    if len(tokenizer) > vocab_size:
        raise AssertionError(f"tokenizer has {len(tokenizer)} tokens > vocab_size {vocab_size}")
    return tokenizer


def install_tokenizer(hub_cache: Path, tokenizer, repo_id: str = PALIGEMMA_TOKENIZER) -> Path:
    """Write ``tokenizer`` into a Hugging Face hub cache as ``repo_id``; returns the snapshot folder."""
    repo = Path(hub_cache) / f"models--{repo_id.replace('/', '--')}"
    snapshot = repo / "snapshots" / _SNAPSHOT
    snapshot.mkdir(parents=True, exist_ok=True)
    tokenizer.save_pretrained(snapshot)
    # transformers 5 reads config.json first to pick the tokenizer class for the model type.
    (snapshot / "config.json").write_text(json.dumps({"model_type": "paligemma"}))
    (repo / "refs").mkdir(exist_ok=True)
    (repo / "refs" / "main").write_text(_SNAPSHOT)
    return snapshot


def _is_loopback(sock: socket.socket, address: Any) -> bool:
    if sock.family == getattr(socket, "AF_UNIX", None):
        return True
    host = address[0] if isinstance(address, tuple) else address
    return str(host) in {"localhost", "127.0.0.1", "::1"} or str(host).startswith("127.")


@dataclass
class TinyPiEnv:
    hub_cache: Path
    tokenizer: Any
    dims: TinyDims
    network_attempts: list[str] = field(default_factory=list)


@contextlib.contextmanager
def no_network(attempts: list[str]) -> Iterator[list[str]]:
    """Refuse (and record) every non-loopback socket connection. Recorded too, because some callers
    (lerobot's pi ``from_pretrained`` among them) swallow exceptions."""
    real_connect, real_connect_ex = socket.socket.connect, socket.socket.connect_ex

    def guard(real):
        def connect(sock, address):
            if not _is_loopback(sock, address):
                attempts.append(repr(address))
                raise OSError(f"network access blocked in tiny VLA tests: {address!r}")
            return real(sock, address)

        return connect

    with (
        mock.patch.object(socket.socket, "connect", guard(real_connect)),
        mock.patch.object(socket.socket, "connect_ex", guard(real_connect_ex)),
    ):
        yield attempts


@contextlib.contextmanager
def offline_hub(hub_cache: Path) -> Iterator[Path]:
    """Point the Hugging Face hub at a private cache and switch it offline.

    huggingface_hub reads HF_HUB_CACHE / HF_HUB_OFFLINE into module constants at import time (often
    before a test starts), so the constants are patched as well as the environment."""
    from huggingface_hub import constants

    hub_cache = Path(hub_cache)
    hub_cache.mkdir(parents=True, exist_ok=True)
    env = {
        "HF_HUB_OFFLINE": "1",
        "TRANSFORMERS_OFFLINE": "1",
        "HF_HOME": str(hub_cache.parent / (hub_cache.name + "_home")),
        "HF_HUB_CACHE": str(hub_cache),
        "HF_HUB_DISABLE_TELEMETRY": "1",
    }
    with (
        mock.patch.dict(os.environ, env),
        mock.patch.object(constants, "HF_HUB_OFFLINE", True),
        mock.patch.object(constants, "HF_HUB_CACHE", str(hub_cache)),
        mock.patch.object(constants, "HUGGINGFACE_HUB_CACHE", str(hub_cache)),
    ):
        yield hub_cache


@contextlib.contextmanager
def tiny_pi_env(hub_cache: Path, dims: TinyDims = DEFAULT_DIMS) -> Iterator[TinyPiEnv]:
    """Everything a tiny pi0 / pi0.5 needs: size substitution, private offline tokenizer cache and a
    network guard. Build, save and reload the policies inside it."""
    attempts: list[str] = []
    with no_network(attempts), offline_hub(hub_cache) as cache, tiny_pi_models(dims):
        tokenizer = build_tiny_tokenizer(dims.vocab_size)
        install_tokenizer(cache, tokenizer)
        yield TinyPiEnv(hub_cache=cache, tokenizer=tokenizer, dims=dims, network_attempts=attempts)


# ----------------------------------------------------------------------------------------------
# Configs, synthetic data, build / load
# ----------------------------------------------------------------------------------------------


def _offsets(dim: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(dim, generator=gen) - 0.5, 0.5 + torch.rand(dim, generator=gen)


def synthetic_stats(state_dim: int = 14, action_dim: int = 14) -> dict[str, dict[str, torch.Tensor]]:
    """Stats of `synthetic_batch`'s uniform vectors, with every key the mean/std, min/max and quantile
    normalisers read (pi0 uses mean/std, pi0.5 q01/q99)."""
    stats = {}
    for key, dim, seed in ((STATE_KEY, state_dim, 1), (ACTION_KEY, action_dim, 2)):
        centre, half = _offsets(dim, seed)
        stats[key] = {
            "mean": centre,
            "std": half / 3**0.5,
            "min": centre - half,
            "max": centre + half,
            "q01": centre - 0.98 * half,
            "q99": centre + 0.98 * half,
            "q10": centre - 0.8 * half,
            "q90": centre + 0.8 * half,
        }
    return stats


def synthetic_batch(
    batch_size: int = 2,
    *,
    state_dim: int = 14,
    action_dim: int = 14,
    chunk_size: int | None = 10,
    cameras: Sequence[str] = CAMERAS,
    image_hw: tuple[int, int] = (64, 64),
    task: str = TASK,
    seed: int = 0,
) -> dict[str, Any]:
    """A raw (pre-processor) batch: uint8 camera frames scaled to [0, 1], uniform state and, unless
    ``chunk_size`` is None, an action chunk."""
    gen = torch.Generator().manual_seed(seed)
    batch: dict[str, Any] = {}
    for cam in cameras:
        frames = torch.randint(0, 256, (batch_size, 3, *image_hw), dtype=torch.uint8, generator=gen)
        batch[cam] = frames.float() / 255.0
    centre, half = _offsets(state_dim, 1)
    batch[STATE_KEY] = centre + half * (2 * torch.rand(batch_size, state_dim, generator=gen) - 1)
    if chunk_size is not None:
        centre, half = _offsets(action_dim, 2)
        noise = 2 * torch.rand(batch_size, chunk_size, action_dim, generator=gen) - 1
        batch[ACTION_KEY] = centre + half * noise
    batch["task"] = [task] * batch_size
    return batch


def tiny_pi_config(
    policy_type: str,
    *,
    state_dim: int = 14,
    action_dim: int = 14,
    cameras: Sequence[str] = CAMERAS,
    image_hw: tuple[int, int] = (64, 64),
    **overrides: Any,
):
    """A stock PI0Config / PI05Config for small inputs: native image resolution (no resize), short
    chunks and prompts, few denoising steps, float32 on CPU."""

    if image_hw[0] != image_hw[1]:
        raise ValueError("PaliGemma needs square images")
    if policy_type == "pi0":
        from lerobot.policies.pi0 import PI0Config as config_cls

        defaults: dict[str, Any] = {"tokenizer_max_length": 32}
    elif policy_type == "pi05":
        from lerobot.policies.pi05 import PI05Config as config_cls

        # The pi0.5 prompt spells out the discretised state, which takes many tiny-tokenizer tokens.
        defaults = {"tokenizer_max_length": 96}
    else:
        raise ValueError(f"policy_type must be 'pi0' or 'pi05', got {policy_type!r}")
    defaults.update(
        chunk_size=10,
        n_action_steps=5,
        num_inference_steps=2,
        # lerobot pads to 32 by default; only grow it for wider robots.
        max_state_dim=max(32, state_dim),
        max_action_dim=max(32, action_dim),
        image_resolution=tuple(image_hw),
        dtype="float32",
        device="cpu",
        push_to_hub=False,
        **policy_features(cameras, image_hw, state_dim, action_dim),
    )
    defaults.update(overrides)
    return config_cls(**defaults)


def policy_class(policy_type: str):
    from lerobot.policies.factory import get_policy_class

    return get_policy_class(policy_type)


def make_tiny_pi(policy_type: str, *, seed: int = 0, **config_kwargs: Any):
    """(policy, preprocessor, postprocessor), freshly initialised. Call inside ``tiny_pi_env``."""
    from lerobot.policies.factory import make_pre_post_processors

    config = tiny_pi_config(policy_type, **config_kwargs)
    torch.manual_seed(seed)
    policy = policy_class(policy_type)(config)
    preprocessor, postprocessor = make_pre_post_processors(
        config,
        dataset_stats=synthetic_stats(
            config.input_features[STATE_KEY].shape[0], config.output_features[ACTION_KEY].shape[0]
        ),
    )
    return policy, preprocessor, postprocessor


def save_tiny_pi(folder: Path, policy, preprocessor, postprocessor) -> Path:
    folder = Path(folder)
    policy.save_pretrained(folder)
    preprocessor.save_pretrained(folder)
    postprocessor.save_pretrained(folder)
    return folder


def build_tiny_pi(
    policy_type: str,
    folder: Path,
    state_dim: int = 14,
    action_dim: int = 14,
    cameras: Sequence[str] = CAMERAS,
    image_hw: tuple[int, int] = (64, 64),
    *,
    seed: int = 0,
    **config_overrides: Any,
) -> Path:
    """Save a freshly initialised tiny pi0 ("pi0") or pi0.5 ("pi05") policy with its processors into
    ``folder`` (a lerobot pretrained-model folder); returns it. Call inside ``tiny_pi_env``; reload
    with ``load_tiny_pi`` inside it too."""
    policy, pre, post = make_tiny_pi(
        policy_type,
        seed=seed,
        state_dim=state_dim,
        action_dim=action_dim,
        cameras=cameras,
        image_hw=image_hw,
        **config_overrides,
    )
    return save_tiny_pi(folder, policy, pre, post)


def load_tiny_pi(folder: Path, *, check_weights: bool = True):
    """(policy, preprocessor, postprocessor) loaded from ``folder`` with lerobot's loaders.

    lerobot's pi ``from_pretrained`` prints and swallows weight-loading errors and then returns random
    weights, so with ``check_weights`` the loaded tensors are compared with the saved file."""
    from lerobot.configs import PreTrainedConfig
    from lerobot.policies.factory import make_pre_post_processors
    from safetensors.torch import load_file

    folder = Path(folder)
    config = PreTrainedConfig.from_pretrained(folder)
    policy = policy_class(config.type).from_pretrained(folder)
    if check_weights:
        problems = state_dict_mismatches(load_file(folder / "model.safetensors"), policy.state_dict())
        if problems:
            raise RuntimeError(f"{folder}: weights did not load: {problems[:5]}")
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(folder))
    return policy, preprocessor, postprocessor


def state_dict_mismatches(expected: dict[str, torch.Tensor], actual: dict[str, torch.Tensor]) -> list[str]:
    """Keys missing on either side, and keys whose tensors differ in shape, dtype or value."""
    problems = [f"missing {key}" for key in expected.keys() - actual.keys()]
    problems += [f"unexpected {key}" for key in actual.keys() - expected.keys()]
    for key in sorted(expected.keys() & actual.keys()):
        a, b = expected[key].detach().cpu(), actual[key].detach().cpu()
        if a.shape != b.shape or a.dtype != b.dtype or not torch.equal(a, b):
            problems.append(f"differs {key}")
    return problems


def parameter_count(policy) -> int:
    return sum(p.numel() for p in policy.parameters())


# ----------------------------------------------------------------------------------------------
# SmolVLA (r2s_eval.policies.tiny) and X-VLA: tiny backbones described by config files in local folders
# ----------------------------------------------------------------------------------------------
#
# Neither family needs a size substitution: SmolVLA builds its VLM from ``AutoConfig`` /
# ``AutoProcessor`` of ``vlm_model_name`` (weights only with ``load_vlm_weights=True``), and X-VLA
# builds Florence-2 from the ``florence_config`` dict in its own config. A local folder holding a tiny
# config and processor is therefore enough, and the saved checkpoints can name the stock hub ids
# (as the LeRobot base checkpoints do) while training and reloading are pointed at the folders.

XVLA_TOKENIZER_HUB_NAME = "facebook/bart-large"


def build_xvla_tokenizer(folder: Path, vocab_size: int = 300) -> Path:
    """A BART-style tokenizer folder (<s> <pad> </s> <unk> <mask>, ids 0..4) for X-VLA's prompt."""
    tokenizer = build_bpe_tokenizer(
        vocab_size,
        ["<s>", "<pad>", "</s>", "<unk>", "<mask>"],
        wrap_with=("<s>", "</s>"),
        bos_token="<s>",
        eos_token="</s>",
        unk_token="<unk>",
        pad_token="<pad>",
        mask_token="<mask>",
    )
    folder = Path(folder)
    tokenizer.save_pretrained(folder)
    return folder


def tiny_florence_config(vocab_size: int, width: int = 32) -> dict[str, Any]:
    """Florence-2 as X-VLA's ``florence_config``: a 4-stage DaViT with one block per stage and a
    1-layer BART encoder (X-VLA drops the decoder), both ``width`` wide where they meet."""
    return {
        "vision_config": {
            "depths": [1, 1, 1, 1],
            "embed_dim": [8, 16, 16, width],
            "num_heads": [1, 1, 1, 2],
            "num_groups": [1, 1, 1, 2],
            "window_size": 2,
            "projection_dim": width,
            "drop_path_rate": 0.0,
            "max_position_embeddings": 16,
            "max_temporal_embeddings": 4,
        },
        "text_config": {
            "model_type": "bart",
            "d_model": width,
            "encoder_layers": 1,
            "decoder_layers": 1,
            "encoder_attention_heads": 2,
            "decoder_attention_heads": 2,
            "encoder_ffn_dim": 2 * width,
            "decoder_ffn_dim": 2 * width,
            "vocab_size": vocab_size,
            "max_position_embeddings": 64,
            "pad_token_id": 1,
            "bos_token_id": 0,
            "eos_token_id": 2,
        },
        "pad_token_id": 1,
        "bos_token_id": 0,
        "eos_token_id": 2,
    }


def tiny_xvla_config(
    tokenizer_dir: Path,
    *,
    state_dim: int = 14,
    action_dim: int = 14,
    cameras: Sequence[str] = CAMERAS,
    image_hw: tuple[int, int] = (64, 64),
    **overrides: Any,
):
    from lerobot.policies.xvla.configuration_xvla import XVLAConfig
    from transformers import AutoTokenizer

    vocab_size = len(AutoTokenizer.from_pretrained(str(tokenizer_dir)))
    kwargs: dict[str, Any] = dict(
        florence_config=tiny_florence_config(vocab_size),
        tokenizer_name=str(tokenizer_dir),
        tokenizer_max_length=16,
        hidden_size=32,
        depth=1,
        num_heads=2,
        num_domains=2,
        len_soft_prompts=4,
        dim_time=8,
        max_len_seq=128,
        action_mode="auto",
        max_state_dim=max(32, state_dim),
        max_action_dim=max(20, action_dim),
        num_denoising_steps=2,
        chunk_size=10,
        n_action_steps=5,
        device="cpu",
        push_to_hub=False,
        **policy_features(cameras, image_hw, state_dim, action_dim),
    )
    kwargs.update(overrides)
    return XVLAConfig(**kwargs)


def build_tiny_xvla(
    folder: Path,
    tokenizer_dir: Path,
    *,
    seed: int = 0,
    hub_name: str | None = XVLA_TOKENIZER_HUB_NAME,
    **config_kwargs: Any,
) -> Path:
    """Save a freshly initialised tiny X-VLA (config.json + model.safetensors) into ``folder``; the
    saved config names ``hub_name`` as its tokenizer, like ``lerobot/xvla-base``."""
    config = tiny_xvla_config(tokenizer_dir, **config_kwargs)
    torch.manual_seed(seed)
    policy = policy_class("xvla")(config)
    if hub_name is not None:
        policy.config.tokenizer_name = hub_name
    policy.save_pretrained(Path(folder))
    return Path(folder)
