"""Object segmentation of a camera frame. Pluggable: anything with `segment(image) -> masks`.

The bundled HSV segmenter (the default) suits objects of distinct saturated colours (our
suite); ``grounded_sam`` (``r2s_eval.calib.open_vocab``) finds objects from text prompts with
Grounding DINO + SAM through transformers, for users who have those weights locally.
"""

from __future__ import annotations

import colorsys
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from r2s_eval.errors import ConfigError


class Segmenter(Protocol):
    def segment(self, image_rgb: np.ndarray) -> dict[str, np.ndarray]:
        """Boolean HxW mask per object name (empty masks for objects not seen)."""


@dataclass(frozen=True)
class HueRange:
    """OpenCV HSV thresholds (hue 0..179, wrapping when lo > hi)."""

    hue_lo: int
    hue_hi: int
    sat_min: int = 90
    val_min: int = 40
    sat_max: int = 255
    val_max: int = 255

    @classmethod
    def around_rgb(cls, rgb: Sequence[float], hue_tol: int = 12, sat_min: int = 90, val_min: int = 40) -> HueRange:
        hue = colorsys.rgb_to_hsv(*rgb[:3])[0] * 180.0
        return cls(int(round(hue - hue_tol)) % 180, int(round(hue + hue_tol)) % 180, sat_min, val_min)

    def mask(self, hsv: np.ndarray) -> np.ndarray:
        h, s, v = hsv[..., 0].astype(int), hsv[..., 1], hsv[..., 2]
        if self.hue_lo <= self.hue_hi:
            in_hue = (h >= self.hue_lo) & (h <= self.hue_hi)
        else:
            in_hue = (h >= self.hue_lo) | (h <= self.hue_hi)
        return in_hue & (s >= self.sat_min) & (s <= self.sat_max) & (v >= self.val_min) & (v <= self.val_max)


MAX_TIGHTENINGS = 3  # how many times a rule that takes in too much is made more saturated


class HSVSegmenter:
    """Colour thresholds per object, keeping the largest connected blob (drops speckle).

    With ``max_area_px`` (per object, the most pixels its silhouette can cover: see
    ``frame_segmenter``) a blob larger than that cannot be the object alone: a background of a near
    hue (a wooden table under a yellow block's rule) passes the rule and swallows it. The rule is
    then made more saturated (the split of Otsu's method over the saturation of the pixels it
    takes in: the object's saturated colour apart from the duller background), up to
    ``MAX_TIGHTENINGS`` times, and the largest blob no larger than the object can be is kept."""

    def __init__(self, ranges: Mapping[str, HueRange], min_area_px: int = 20, blur_px: int = 0,
                 max_area_px: Mapping[str, float] | None = None):
        self.ranges = dict(ranges)
        self.min_area_px = min_area_px
        self.blur_px = blur_px
        self.max_area_px = dict(max_area_px or {})

    def segment(self, image_rgb: np.ndarray) -> dict[str, np.ndarray]:
        # An optional blur makes thresholds robust to heavy sensor noise, but it rounds the
        # corners of small objects (a block's yaw is read from them); off by default.
        if self.blur_px:
            image_rgb = cv2.GaussianBlur(image_rgb, (self.blur_px, self.blur_px), 0)
        hsv = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2HSV)
        return {name: self._object_blob(hsv, rng, self.max_area_px.get(name)) for name, rng in self.ranges.items()}

    def _object_blob(self, hsv: np.ndarray, rule: HueRange, max_area: float | None) -> np.ndarray:
        mask = rule.mask(hsv)
        if max_area is None:
            return self._largest_blob(mask)
        for _ in range(MAX_TIGHTENINGS):
            if self._largest_blob(mask).sum() <= max_area:
                break
            saturations = hsv[..., 1][mask].astype(np.uint8).reshape(-1, 1)
            split, _ = cv2.threshold(saturations, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
            if split < rule.sat_min:
                break
            rule = dataclasses.replace(rule, sat_min=int(split) + 1)
            mask = rule.mask(hsv)
        return self._largest_blob(mask, max_area)

    def _largest_blob(self, mask: np.ndarray, max_area: float | None = None) -> np.ndarray:
        """The mask's largest connected blob (of at most ``max_area`` pixels), or an empty mask
        where none reaches ``min_area_px``."""
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
        if n <= 1:
            return np.zeros(mask.shape, bool)
        areas = stats[1:, cv2.CC_STAT_AREA].astype(float)
        if max_area is not None:
            areas[areas > max_area] = -1.0
        best = 1 + int(np.argmax(areas))
        if areas[best - 1] < self.min_area_px:
            return np.zeros(mask.shape, bool)
        return labels == best


def make_segmenter(cfg: Mapping, object_rgba: Mapping[str, Sequence[float]],
                   find: Mapping[str, Mapping] | None = None,
                   max_area_px: Mapping[str, float] | None = None) -> Segmenter:
    """Build the configured segmenter for the objects of `object_rgba` (their nominal colours).

    cfg: {"type": "hsv", "hue_tol": 12, "sat_min": 90, "val_min": 40, "blur_px": 0}
    or {"type": "grounded_sam", ...} (see ``r2s_eval.calib.open_vocab``). `find`: per object how
    the world says it is found (an ``ObjectSpec``'s ``hue`` range and ``prompt``; absent: the
    defaults, a range around its colour and "a <name>"). `max_area_px`: per object, the most
    pixels it can cover (the hsv segmenter's plausibility check, ``HSVSegmenter``; None: none).
    """
    find = find or {}
    kind = cfg.get("type", "hsv")
    if kind == "grounded_sam":
        from r2s_eval.calib.open_vocab import make_grounded_sam

        return make_grounded_sam(cfg, {name: (find.get(name) or {}).get("prompt") for name in object_rgba})
    if kind != "hsv":
        raise ConfigError(f"unknown segmenter type {kind!r} (available: hsv, grounded_sam)")
    ranges = {}
    for name, rgba in object_rgba.items():
        if (find.get(name) or {}).get("hue"):
            ranges[name] = HueRange(**find[name]["hue"])
        else:
            ranges[name] = HueRange.around_rgb(
                rgba, cfg.get("hue_tol", 12), cfg.get("sat_min", 90), cfg.get("val_min", 40)
            )
    return HSVSegmenter(ranges, min_area_px=cfg.get("min_area_px", 20), blur_px=int(cfg.get("blur_px", 0)),
                        max_area_px=max_area_px)


def finders(objects) -> dict[str, dict]:
    """``find`` of ``make_segmenter`` from the world's objects (``ObjectSpec``: hue, prompt)."""
    return {o.name: {"hue": o.hue, "prompt": o.prompt} for o in objects}
