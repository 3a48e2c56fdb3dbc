"""The transformers backend end to end, with a tiny randomly initialised Qwen3-VL: on CPU, and on
CUDA too where a GPU is present (skipped otherwise).

The model, its tokenizer (a byte-level BPE trained here) and its processor are built offline from
their configs and saved to a folder; the judge then loads that folder through AutoProcessor and
AutoModelForImageTextToText exactly as it would load a downloaded checkpoint.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from r2s_eval.compare import wins_at_checkpoints
from r2s_eval.compare.sampling import sample_pairs, sample_reserve
from r2s_eval.judge import CRITERIA, Description, describe_rollouts, judge_pairs, make_judge
from r2s_eval.rollout.episode_store import load_episodes


from tests.helpers.videos import make_rollouts

transformers = pytest.importorskip("transformers")
torch = pytest.importorskip("torch")

SPECIAL = ["<|endoftext|>", "<|im_start|>", "<|im_end|>", "<|vision_start|>", "<|vision_end|>",
           "<|image_pad|>", "<|video_pad|>"]
# Qwen-style chat template: text, images and videos in order, then the assistant turn.
CHAT_TEMPLATE = (
    "{% for m in messages %}<|im_start|>{{ m['role'] }}\n"
    "{% if m['content'] is string %}{{ m['content'] }}{% else %}{% for c in m['content'] %}"
    "{% if c['type'] == 'image' %}<|vision_start|><|image_pad|><|vision_end|>"
    "{% elif c['type'] == 'video' %}<|vision_start|><|video_pad|><|vision_end|>"
    "{% else %}{{ c['text'] }}{% endif %}{% endfor %}{% endif %}<|im_end|>\n{% endfor %}"
    "{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)
CORPUS = [
    "Motion smoothness: the arm moves smoothly. Action continuity: no pauses.",
    "Task success: successful, partially successful or failed. Force/effort control: gentle.",
    "Summary: a clean execution. Answer with exactly one letter: A or B.",
]


def build_tiny_qwen3_vl(folder: Path) -> dict[str, int]:
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import (
        Qwen2TokenizerFast,
        Qwen2VLImageProcessorFast,
        Qwen3VLConfig,
        Qwen3VLForConditionalGeneration,
        Qwen3VLProcessor,
    )
    from transformers.models.qwen3_vl.video_processing_qwen3_vl import Qwen3VLVideoProcessor

    bpe = Tokenizer(models.BPE())
    bpe.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    bpe.decoder = decoders.ByteLevel()
    bpe.train_from_iterator(CORPUS * 5, trainers.BpeTrainer(
        vocab_size=400, special_tokens=SPECIAL, initial_alphabet=pre_tokenizers.ByteLevel.alphabet()))
    tok = Qwen2TokenizerFast(tokenizer_object=bpe, eos_token="<|im_end|>", pad_token="<|endoftext|>",
                             unk_token=None, additional_special_tokens=SPECIAL[1:])
    tok.chat_template = CHAT_TEMPLATE
    image_proc = Qwen2VLImageProcessorFast(patch_size=16, merge_size=2, temporal_patch_size=2,
                                           min_pixels=32 * 32, max_pixels=64 * 64)
    video_proc = Qwen3VLVideoProcessor(patch_size=16, merge_size=2, temporal_patch_size=2)
    processor = Qwen3VLProcessor(image_processor=image_proc, tokenizer=tok, video_processor=video_proc,
                                 chat_template=CHAT_TEMPLATE)
    ids = {t: tok.convert_tokens_to_ids(t) for t in SPECIAL}
    config = Qwen3VLConfig(
        text_config=dict(
            vocab_size=len(tok), hidden_size=64, intermediate_size=128, num_hidden_layers=2,
            num_attention_heads=4, num_key_value_heads=2, head_dim=16, max_position_embeddings=4096,
            rope_scaling={"rope_type": "default", "mrope_section": [2, 3, 3], "mrope_interleaved": True},
        ),
        vision_config=dict(
            depth=2, hidden_size=32, intermediate_size=64, num_heads=2, patch_size=16, spatial_merge_size=2,
            temporal_patch_size=2, out_hidden_size=64, num_position_embeddings=64, deepstack_visual_indexes=[1],
        ),
        image_token_id=ids["<|image_pad|>"], video_token_id=ids["<|video_pad|>"],
        vision_start_token_id=ids["<|vision_start|>"], vision_end_token_id=ids["<|vision_end|>"],
        tie_word_embeddings=True,
    )
    torch.manual_seed(0)
    model = Qwen3VLForConditionalGeneration(config).eval()
    model.generation_config.eos_token_id = ids["<|im_end|>"]
    model.generation_config.pad_token_id = ids["<|endoftext|>"]
    model.save_pretrained(folder)
    processor.save_pretrained(folder)
    return {"A": tok.convert_tokens_to_ids("A"), "B": tok.convert_tokens_to_ids("B"), "vocab": len(tok)}


@pytest.fixture(scope="module")
def tiny_models(tmp_path_factory):
    """Two checkpoints of one random model: as built, and with a generation config that only lets
    it say 'A' or 'B' (and stop), so its comparisons are valid and depend on what it is shown."""
    from transformers import GenerationConfig

    root = tmp_path_factory.mktemp("models")
    free = root / "qwen3-vl-tiny"
    ids = build_tiny_qwen3_vl(free)
    letters = root / "qwen3-vl-tiny-letters"
    shutil.copytree(free, letters)
    gen = GenerationConfig.from_pretrained(letters)
    gen.suppress_tokens = [i for i in range(ids["vocab"]) if i not in (ids["A"], ids["B"])]
    gen.eos_token_id = [ids["A"], ids["B"]]
    gen.save_pretrained(letters)
    return free, letters


@pytest.fixture
def rollouts(tmp_path):
    levels = {(p, "lift", i): lvl + 0.02 * i for p, lvl in (("P_good", 0.8), ("P_bad", 0.2)) for i in range(3)}
    dirs = make_rollouts(tmp_path / "rollouts", levels)
    return load_episodes(dirs)


def cfg(model: Path, **kw) -> dict:
    return {"backend": "transformers", "model": str(model), "family": "qwen3_vl", "device": "cpu",
            "dtype": "float32", "max_frames": 4, "max_new_tokens": 12, "local_files_only": True, **kw}


DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU"))]


@pytest.mark.parametrize("device", DEVICES)
def test_transformers_judge_end_to_end(device, tiny_models, rollouts, tmp_path):
    free, letters = tiny_models
    cache = tmp_path / "cache"
    judge = make_judge(cfg(free, device=device))
    desc = describe_rollouts(rollouts, ".", judge, cache)
    assert judge._model.device.type == device
    st = desc.attrs["stats"]
    assert st["calls"] == st["requests"] == len(rollouts)
    assert st["tokens_in"] > 4 * len(rollouts) and 0 < st["tokens_out"] <= 12 * len(rollouts)
    # A random model writes no usable sections: every one is flagged, and its reply is kept.
    for js in desc["description"]:
        d = Description.from_json(js)
        assert d.missing == (*CRITERIA, "summary") and d.raw_text
    assert (desc["missing"] != "").all() and st["incomplete"] == len(rollouts)
    assert describe_rollouts(rollouts, ".", make_judge(cfg(free, device=device)), cache).attrs["stats"]["calls"] == 0

    # The letter-constrained checkpoint: valid verdicts, a wins matrix, the order-swap audit.
    policies, checkpoints = ["P_bad", "P_good"], [3, 6]
    pairs = sample_pairs(rollouts, policies, checkpoints, seed=0)
    out = judge_pairs(pairs, desc, make_judge(cfg(letters, device=device, swap_share=1.0)), cache)
    assert set(out["verdict"]) <= {"A", "B"} and (out["verdict_swapped"] != "").all()
    assert out.attrs["stats"]["excluded"] == 0 and 0.0 <= out.attrs["stats"]["swap_consistency"] <= 1.0
    assert wins_at_checkpoints(out, policies, checkpoints)[-1].sum() == checkpoints[-1]

    # The unconstrained model never answers with one letter: re-asked, excluded, replaced from
    # the reserve until that runs out, which names the pair.
    reserve = sample_reserve(rollouts, policies, checkpoints, seed=0, n_reserve=1)
    free_judge = make_judge(cfg(free, device=device))
    with pytest.raises(RuntimeError, match=r"pair row \d+ \(P_\w+ vs P_\w+.*no reserve comparison is left"):
        judge_pairs(pairs, desc, free_judge, cache, reserve_df=reserve)


def test_transformers_judge_config_errors_are_clear(tmp_path):
    with pytest.raises(ValueError, match="unknown family 'llama'"):
        make_judge(cfg(tmp_path, family="llama"))
    with pytest.raises(ValueError, match="unknown config keys \\['temprature'\\]"):
        make_judge(cfg(tmp_path, temprature=0.0))
    judge = make_judge(cfg(tmp_path / "nowhere"))
    with pytest.raises(RuntimeError, match="cannot load qwen3_vl model from .*nowhere"):
        judge._load()
