"""Evenly spaced frames from a rollout video, for figures."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np

from r2s_eval.errors import ConfigError, DataError


def sample_frames(path: str | Path, n: int) -> tuple[list[np.ndarray], list[float]]:
    """Decode ``n`` frames evenly spaced from the first to the last (RGB uint8) and their
    times in seconds. A video shorter than ``n`` frames gives all of its frames."""
    if n < 1:
        raise ConfigError(f"need at least one frame, got n={n}")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"rollout video not found: {path}")
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        fps = float(stream.average_rate) if stream.average_rate else 1.0
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(stream)]
    if not frames:
        raise DataError(f"{path}: no decodable frames")
    picks = np.unique(np.linspace(0, len(frames) - 1, n).round().astype(int))
    return [frames[k] for k in picks], [k / fps for k in picks]
