"""Open-vocabulary segmenter (Grounding DINO + SAM through transformers) on tiny local models.

The models are random, built from small configs and saved to a temp folder: the test checks
the plumbing (local loading, prompts, boxes -> SAM masks -> per-object masks), not accuracy.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("transformers")

from transformers import (  # noqa: E402
    BertConfig,
    BertTokenizerFast,
    GroundingDinoConfig,
    GroundingDinoForObjectDetection,
    GroundingDinoImageProcessor,
    GroundingDinoProcessor,
    SamConfig,
    SamImageProcessor,
    SamModel,
    SamProcessor,
    SwinConfig,
)
from transformers.models.sam.configuration_sam import (  # noqa: E402
    SamMaskDecoderConfig,
    SamPromptEncoderConfig,
    SamVisionConfig,
)

from r2s_eval.calib import HSVSegmenter, make_segmenter  # noqa: E402

OBJECTS = {"cup": (0.85, 0.08, 0.08, 1.0), "ball": (0.1, 0.75, 0.15, 1.0)}


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    import torch

    root = tmp_path_factory.mktemp("open_vocab")
    vocab = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", "a", "red", "cup", "green", "ball"]
    (root / "vocab.txt").write_text("\n".join(vocab) + "\n")
    tokenizer = BertTokenizerFast(vocab_file=str(root / "vocab.txt"))
    det_processor = GroundingDinoProcessor(
        image_processor=GroundingDinoImageProcessor(size={"shortest_edge": 64, "longest_edge": 64}), tokenizer=tokenizer
    )
    det_config = GroundingDinoConfig(
        backbone_config=SwinConfig(image_size=64, embed_dim=8, depths=[1, 1, 1, 1], num_heads=[1, 1, 1, 1],
                                   window_size=2, out_features=["stage2", "stage3", "stage4"]),
        text_config=BertConfig(vocab_size=len(vocab), hidden_size=32, num_hidden_layers=1, num_attention_heads=2,
                               intermediate_size=32),
        # decoder_layers >= 2: with the default decoder_bbox_embed_share the model ties bbox_embed.1.. to
        # bbox_embed.0, and transformers 5 rejects a tie pattern with nothing to tie (one decoder layer).
        d_model=32, encoder_layers=1, decoder_layers=2, encoder_attention_heads=2, decoder_attention_heads=2,
        encoder_ffn_dim=32, decoder_ffn_dim=32, num_queries=5, num_feature_levels=3, max_text_len=16,
        encoder_n_points=1, decoder_n_points=1,
    )
    sam_config = SamConfig(
        vision_config=SamVisionConfig(hidden_size=16, num_hidden_layers=1, num_attention_heads=2, image_size=64,
                                      patch_size=16, output_channels=16, mlp_dim=32, global_attn_indexes=[0],
                                      window_size=2, num_pos_feats=8),
        prompt_encoder_config=SamPromptEncoderConfig(hidden_size=16, image_size=64, patch_size=16,
                                                     mask_input_channels=4, image_embedding_size=4),
        mask_decoder_config=SamMaskDecoderConfig(hidden_size=16, num_attention_heads=2, mlp_dim=32,
                                                 iou_head_hidden_dim=16),
    )
    torch.manual_seed(0)
    GroundingDinoForObjectDetection(det_config).save_pretrained(root / "det")
    det_processor.save_pretrained(root / "det")
    SamModel(sam_config).save_pretrained(root / "sam")
    SamProcessor(image_processor=SamImageProcessor(size={"longest_edge": 64},
                                                   pad_size={"height": 64, "width": 64})).save_pretrained(root / "sam")
    return root / "det", root / "sam"


def test_grounded_sam_loads_locally_and_returns_a_mask_per_object(checkpoints):
    det, sam = checkpoints
    segmenter = make_segmenter(
        {"type": "grounded_sam", "detector_path": str(det), "sam_path": str(sam), "box_threshold": 0.0,
         "text_threshold": 0.0},
        OBJECTS, {"cup": {"prompt": "a red cup"}},  # the world's prompt for the cup; the ball has none
    )
    assert segmenter.prompts == {"cup": "a red cup", "ball": "a ball"}  # default prompt from the name
    image = np.random.default_rng(0).integers(0, 255, (96, 128, 3), dtype=np.uint8)
    boxes = segmenter.detect(image)
    assert set(boxes) == {"cup", "ball"}  # threshold 0: every prompt yields its best box
    for (x0, y0, x1, y1), score in boxes.values():
        assert 0 <= x0 <= x1 <= 127 and 0 <= y0 <= y1 <= 95 and 0.0 <= score <= 1.0
    masks = segmenter.segment(image)
    assert set(masks) == {"cup", "ball"}
    assert all(m.shape == (96, 128) and m.dtype == bool for m in masks.values())


def test_nothing_detected_gives_empty_masks(checkpoints):
    det, sam = checkpoints
    segmenter = make_segmenter({"type": "grounded_sam", "detector_path": str(det), "sam_path": str(sam),
                                "box_threshold": 1.01}, OBJECTS)
    masks = segmenter.segment(np.zeros((64, 64, 3), np.uint8))
    assert all(not m.any() for m in masks.values())


def test_missing_checkpoint_is_named_and_never_downloaded(tmp_path):
    with pytest.raises(FileNotFoundError, match="detector_path.*never downloaded"):
        make_segmenter({"type": "grounded_sam", "detector_path": str(tmp_path / "nope"), "sam_path": str(tmp_path)},
                       OBJECTS)
    with pytest.raises(ValueError, match="sam_path is required"):
        make_segmenter({"type": "grounded_sam", "detector_path": str(tmp_path)}, OBJECTS)


def test_unloadable_checkpoint_names_the_folder(checkpoints, tmp_path):
    det, _ = checkpoints
    empty = tmp_path / "empty_sam"
    empty.mkdir()
    with pytest.raises(RuntimeError, match=r"sam_path: could not load .* from .*empty_sam"):
        make_segmenter({"type": "grounded_sam", "detector_path": str(det), "sam_path": str(empty)}, OBJECTS)


def test_hsv_stays_the_default():
    assert isinstance(make_segmenter({}, OBJECTS), HSVSegmenter)
