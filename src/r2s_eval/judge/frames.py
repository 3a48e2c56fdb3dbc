"""Turn a rollout video into what a VLM is shown: frames sampled at a fixed rate, within a budget.

Frames are taken at ``fps`` (10 per second by default) from the decoded video; when that gives
more than ``max_frames``, they are either spread uniformly over the whole video ("subsample", the
default: the model still sees the end, where success is decided) or cut after the first
``max_frames`` ("truncate"). ``max_side_px`` optionally shrinks frames (keeping the aspect ratio).
"""

from __future__ import annotations

import base64
import hashlib
import io
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

OVER_BUDGET = ("subsample", "truncate")


@dataclass(frozen=True)
class Clip:
    """Sampled frames of one video: (T, H, W, 3) uint8, their times, and a content hash."""

    frames: np.ndarray
    times_s: np.ndarray
    duration_s: float

    @property
    def sha256(self) -> str:
        h = hashlib.sha256(repr(self.frames.shape).encode())
        h.update(np.ascontiguousarray(self.frames).tobytes())
        return h.hexdigest()

    @property
    def fps(self) -> float:
        """Average rate of the sampled frames over the video."""
        return len(self.frames) / self.duration_s if self.duration_s > 0 else float(len(self.frames))


def _decode(path: Path) -> tuple[list[np.ndarray], np.ndarray, float]:
    import av

    frames, times = [], []
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            rate = float(stream.average_rate or stream.guessed_rate or 10)
            for f in container.decode(video=0):
                frames.append(f.to_ndarray(format="rgb24"))
                times.append(float(f.time) if f.time is not None else len(times) / rate)
    except (av.error.FFmpegError, IndexError) as e:
        raise ValueError(f"{path}: cannot decode video ({e})") from e
    if not frames:
        raise ValueError(f"{path}: the video has no frames")
    t = np.asarray(times) - times[0]
    return frames, t, float(t[-1] + 1.0 / rate)


def _resize(frames: np.ndarray, max_side_px: int | None) -> np.ndarray:
    h, w = frames.shape[1:3]
    if not max_side_px or max(h, w) <= max_side_px:
        return frames
    from PIL import Image

    scale = max_side_px / max(h, w)
    size = (max(2, round(w * scale) // 2 * 2), max(2, round(h * scale) // 2 * 2))  # even sizes for H.264
    return np.stack([np.asarray(Image.fromarray(f).resize(size, Image.BICUBIC)) for f in frames])


def sample_clip(
    path: str | Path,
    fps: float = 10.0,
    max_frames: int = 32,
    over_budget: str = "subsample",
    max_side_px: int | None = None,
) -> Clip:
    if fps <= 0 or max_frames < 1:
        raise ValueError(f"frame sampling needs fps > 0 and max_frames >= 1, got {fps}, {max_frames}")
    if over_budget not in OVER_BUDGET:
        raise ValueError(f"over_budget must be one of {OVER_BUDGET}, got {over_budget!r}")
    path = Path(path)
    frames, t, duration = _decode(path)
    targets = np.arange(0.0, duration - 1e-9, 1.0 / fps)
    # The frame shown at each target time; a higher rate than the video's repeats no frame.
    idx = np.unique(np.clip(np.searchsorted(t, targets + 1e-6, side="right") - 1, 0, len(frames) - 1))
    if len(idx) > max_frames:
        if over_budget == "subsample":
            idx = idx[np.round(np.linspace(0, len(idx) - 1, max_frames)).astype(int)]
        else:
            idx = idx[:max_frames]
            duration = float(t[idx[-1]] + 1.0 / fps)
    arr = _resize(np.stack([frames[i] for i in idx]), max_side_px)
    return Clip(frames=arr, times_s=t[idx], duration_s=duration)


def jpeg_data_urls(clip: Clip, quality: int = 90) -> list[str]:
    from PIL import Image

    urls = []
    for f in clip.frames:
        buf = io.BytesIO()
        Image.fromarray(f).save(buf, format="JPEG", quality=quality)
        urls.append("data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode())
    return urls


def mp4_data_url(clip: Clip) -> str:
    """The sampled frames as one H.264 video at their own rate (for servers that take video parts)."""
    from r2s_eval.rollout.video import write_video

    frames = clip.frames
    h, w = frames.shape[1:3]
    if h % 2 or w % 2:  # H.264 with yuv420p needs even sizes
        frames = frames[:, : h // 2 * 2, : w // 2 * 2]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "clip.mp4"
        write_video(out, list(frames), fps=max(1, round(clip.fps)))
        return "data:video/mp4;base64," + base64.b64encode(out.read_bytes()).decode()


def pil_frames(clip: Clip) -> list:
    from PIL import Image

    return [Image.fromarray(f) for f in clip.frames]
