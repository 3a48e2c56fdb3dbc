"""Turn a rollout video into what a VLM is shown: the same number of frames for every clip.

Every clip becomes exactly ``n_frames`` frames (the judge's ``max_frames``, 32 by default), taken
at evenly spaced positions from its first frame to its last; a clip with fewer decoded frames than
that repeats some of them. Why a fixed count and not a fixed rate: episodes stop shortly after
success and run to the time limit otherwise, so a frame count that grows with the clip (or a
stated duration, frame rate or timestamp) would tell successes from failures without looking at
the robot. A ``Clip`` therefore carries the pixels and nothing about timing, and the one video
part sent in ``video`` mode is encoded at a fixed rate (``VIDEO_PART_FPS``), so its frame count,
rate and duration are the same for every clip too. The first and last frames are always included:
the end is where success is decided. ``max_side_px`` optionally shrinks frames (keeping the aspect
ratio).
"""

from __future__ import annotations

import base64
import hashlib
import io
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from r2s_eval.errors import DataError

# Frame rate written into the video part of ``video`` mode. Fixed, never the clip's own, so the
# container's duration and timestamps (which e.g. Qwen-VL servers turn into text) are the same for
# every clip: n_frames / VIDEO_PART_FPS seconds. 2 is the rate vLLM samples Qwen-VL videos at, so
# the server keeps every frame it is sent.
VIDEO_PART_FPS = 2


@dataclass(frozen=True)
class Clip:
    """The frames of one video as a judge sees them: (n_frames, H, W, 3) uint8, nothing else."""

    frames: np.ndarray

    @property
    def sha256(self) -> str:
        h = hashlib.sha256(repr(self.frames.shape).encode())
        h.update(np.ascontiguousarray(self.frames).tobytes())
        return h.hexdigest()


def _decode(path: Path) -> list[np.ndarray]:
    import av

    frames = []
    try:
        with av.open(str(path)) as container:
            for f in container.decode(video=0):
                frames.append(f.to_ndarray(format="rgb24"))
    except (av.error.FFmpegError, IndexError) as e:
        raise DataError(f"{path}: cannot decode video ({e})") from e
    if not frames:
        raise DataError(f"{path}: the video has no frames")
    return frames


def _resize(frames: np.ndarray, max_side_px: int | None) -> np.ndarray:
    h, w = frames.shape[1:3]
    if not max_side_px or max(h, w) <= max_side_px:
        return frames
    from PIL import Image

    scale = max_side_px / max(h, w)
    size = (max(2, round(w * scale) // 2 * 2), max(2, round(h * scale) // 2 * 2))  # even sizes for H.264
    return np.stack([np.asarray(Image.fromarray(f).resize(size, Image.BICUBIC)) for f in frames])


def frame_indices(n_decoded: int, n_frames: int) -> np.ndarray:
    """`n_frames` indices into a clip of `n_decoded` frames, evenly spaced from the first to the last.

    Always exactly `n_frames` of them, whatever `n_decoded` is (a short clip repeats frames), so the
    number of frames shown never depends on the clip's length.
    """
    if n_decoded < 1 or n_frames < 1:
        raise ValueError(f"frame sampling needs a decoded and a requested frame, got {n_decoded}, {n_frames}")
    return np.round(np.linspace(0, n_decoded - 1, n_frames)).astype(int)


def sample_clip(path: str | Path, n_frames: int = 32, max_side_px: int | None = None) -> Clip:
    """Exactly `n_frames` frames of the video at `path`, spread evenly over it (see the module docstring)."""
    frames = _decode(Path(path))
    idx = frame_indices(len(frames), int(n_frames))
    return Clip(frames=_resize(np.stack([frames[i] for i in idx]), max_side_px))


def jpeg_data_urls(clip: Clip, quality: int = 90) -> list[str]:
    from PIL import Image

    urls = []
    for f in clip.frames:
        buf = io.BytesIO()
        Image.fromarray(f).save(buf, format="JPEG", quality=quality)
        urls.append("data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode())
    return urls


def mp4_data_url(clip: Clip) -> str:
    """The frames as one H.264 video at ``VIDEO_PART_FPS`` (for servers that take video parts)."""
    from r2s_eval.rollout.mp4 import write_video

    frames = clip.frames
    h, w = frames.shape[1:3]
    if h % 2 or w % 2:  # H.264 with yuv420p needs even sizes
        frames = frames[:, : h // 2 * 2, : w // 2 * 2]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "clip.mp4"
        write_video(out, list(frames), fps=VIDEO_PART_FPS)
        return "data:video/mp4;base64," + base64.b64encode(out.read_bytes()).decode()


def pil_frames(clip: Clip) -> list:
    from PIL import Image

    return [Image.fromarray(f) for f in clip.frames]
