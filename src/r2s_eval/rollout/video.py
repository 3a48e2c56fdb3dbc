"""Rollout videos: H.264 mp4 (yuv420p), the format VLM servers and browsers accept."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import av
import numpy as np

from r2s_eval.utils.io import atomic_path


def write_video(path: str | Path, frames: Sequence[np.ndarray], fps: int) -> None:
    """Encode RGB uint8 frames (all HxWx3, even sizes) to `path` atomically."""
    if not len(frames):
        raise ValueError(f"no frames to write to {path}")
    height, width = frames[0].shape[:2]
    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            stream = container.add_stream("libx264", rate=int(fps))
            stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
            # Deterministic output: one thread, fixed settings.
            stream.codec_context.options = {"crf": "20", "preset": "veryfast", "threads": "1"}
            for image in frames:
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
                for packet in stream.encode(frame):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)


def read_video(path: str | Path) -> np.ndarray:
    """Decode all frames as uint8 (T, H, W, 3)."""
    with av.open(str(path)) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])
