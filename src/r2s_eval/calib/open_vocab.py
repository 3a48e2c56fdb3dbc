"""Open-vocabulary segmentation: Grounding DINO boxes from text prompts, SAM masks inside them.

For scenes where colour thresholds do not separate the objects (clutter, similar colours,
real lighting). Both models load through transformers from local folders given in the
config (``local_files_only``: nothing is ever downloaded); users point them at checkpoints
they already have, e.g. ``grounding-dino-tiny`` and ``sam-vit-base`` saved with
``save_pretrained``. Same protocol as every segmenter: ``segment(image) -> {name: mask}``.

Config (``calib.segmenter``)::

    type: grounded_sam
    detector_path: /models/grounding-dino-tiny    # folder with config, weights, processor
    sam_path: /models/sam-vit-base
    prompts: {cup: "a red cup", ball: "a green ball"}   # default: "a <object name>"
    box_threshold: 0.3
    text_threshold: 0.25
    device: cpu
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from r2s_eval.errors import ConfigError, EstimationError


def _load(label: str, path: str | Path, cls):
    """``cls.from_pretrained`` on a local folder only; a failure names the config key and the folder."""
    try:
        return cls.from_pretrained(path, local_files_only=True)
    except Exception as exc:
        raise EstimationError(
            f"calib.segmenter.{label}: could not load {cls.__name__} from {path} "
            f"(a local checkpoint saved with save_pretrained; weights are never downloaded): {exc}"
        ) from exc


class GroundedSAMSegmenter:
    """One detector query per object (its best box), then one SAM pass for all boxes."""

    def __init__(self, detector_path: str | Path, sam_path: str | Path, prompts: Mapping[str, str],
                 box_threshold: float = 0.3, text_threshold: float = 0.25, device: str = "cpu"):
        import torch  # heavy imports only for users of this backend
        from transformers import AutoModelForZeroShotObjectDetection, AutoProcessor, SamModel, SamProcessor

        for label, path in (("detector_path", detector_path), ("sam_path", sam_path)):
            if not Path(path).is_dir():
                raise FileNotFoundError(
                    f"calib.segmenter.{label}: {path} is not a folder; point it at a local checkpoint "
                    "saved with save_pretrained (weights are never downloaded)"
                )
        self._torch = torch
        self.device = device
        self.prompts = dict(prompts)
        self.box_threshold, self.text_threshold = box_threshold, text_threshold
        self.det_processor = _load("detector_path", detector_path, AutoProcessor)
        self.detector = _load("detector_path", detector_path, AutoModelForZeroShotObjectDetection)
        self.sam_processor = _load("sam_path", sam_path, SamProcessor)
        self.sam = _load("sam_path", sam_path, SamModel)
        self.detector.to(device).eval()
        self.sam.to(device).eval()

    @staticmethod
    def _query(prompt: str) -> str:
        # Grounding DINO expects lower-case phrases each ending with a period.
        text = prompt.strip().lower()
        return text if text.endswith(".") else text + "."

    def detect(self, image_rgb: np.ndarray) -> dict[str, tuple[list[float], float]]:
        """Best box (x0, y0, x1, y1 in pixels) and score per object above the thresholds."""
        torch = self._torch
        h, w = image_rgb.shape[:2]
        boxes = {}
        for name, prompt in self.prompts.items():
            inputs = self.det_processor(images=image_rgb, text=self._query(prompt), return_tensors="pt").to(self.device)
            with torch.no_grad():
                outputs = self.detector(**inputs)
            result = self.det_processor.post_process_grounded_object_detection(
                outputs, inputs["input_ids"], threshold=self.box_threshold, text_threshold=self.text_threshold,
                target_sizes=[(h, w)],
            )[0]
            if len(result["scores"]):
                best = int(torch.argmax(result["scores"]))
                box = result["boxes"][best].clamp(min=0).tolist()
                box = [min(box[0], w - 1), min(box[1], h - 1), min(box[2], w - 1), min(box[3], h - 1)]
                boxes[name] = (box, float(result["scores"][best]))
        return boxes

    def segment(self, image_rgb: np.ndarray) -> dict[str, np.ndarray]:
        torch = self._torch
        h, w = image_rgb.shape[:2]
        masks = {name: np.zeros((h, w), bool) for name in self.prompts}
        boxes = self.detect(image_rgb)
        if not boxes:
            return masks
        names = list(boxes)
        inputs = self.sam_processor(image_rgb, input_boxes=[[boxes[n][0] for n in names]], return_tensors="pt")
        inputs = inputs.to(self.device)
        with torch.no_grad():
            outputs = self.sam(**inputs, multimask_output=False)
        predicted = self.sam_processor.image_processor.post_process_masks(
            outputs.pred_masks.cpu(), inputs["original_sizes"].cpu(), inputs["reshaped_input_sizes"].cpu()
        )[0]  # (n_boxes, 1, H, W)
        for i, name in enumerate(names):
            masks[name] = predicted[i, 0].numpy().astype(bool)
        return masks


def make_grounded_sam(cfg: Mapping, prompts: Mapping[str, str | None]) -> GroundedSAMSegmenter:
    """The segmenter for the objects of ``prompts`` ({name: the world's prompt, or None for "a <name>"})."""
    prompts = {name: prompt or f"a {name.replace('_', ' ')}" for name, prompt in prompts.items()}
    for key in ("detector_path", "sam_path"):
        if not cfg.get(key):
            raise ConfigError(f"calib.segmenter.{key} is required for type grounded_sam (a local checkpoint folder)")
    return GroundedSAMSegmenter(cfg["detector_path"], cfg["sam_path"], prompts,
                                box_threshold=float(cfg.get("box_threshold", 0.3)),
                                text_threshold=float(cfg.get("text_threshold", 0.25)), device=cfg.get("device", "cpu"))
