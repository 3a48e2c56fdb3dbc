"""Training data: a LeRobotDataset whose camera frames are decoded once and served from memory.

`LeRobotDataset.__getitem__` decodes every camera of the dataset for every sample, seeking in the
video each time. On a CPU budget of minutes that dominates training, and most cameras are not
policy inputs. `FrameCachedDataset` keeps lerobot's indexing (delta timestamps, padding masks,
episode boundaries, stats) and only replaces the video query: the selected cameras are decoded
sequentially once (PyAV), other cameras are never touched.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.utils.constants import ACTION, OBS_STATE

from r2s_eval.errors import DataError


class DatasetContractError(DataError):
    """The dataset on disk does not provide what the policy config asks for."""


def check_features(meta: LeRobotDatasetMetadata, image_keys: list[str]) -> None:
    """Raise `DatasetContractError` naming the dataset and the missing / malformed key."""
    where = f"dataset {meta.repo_id!r} at {meta.root}"
    for key in (OBS_STATE, ACTION):
        if key not in meta.features:
            raise DatasetContractError(f"{where} has no feature {key!r}")
    for key in image_keys:
        if key not in meta.features:
            raise DatasetContractError(
                f"{where} has no camera {key!r}; cameras present: {sorted(meta.camera_keys)}"
            )
        if key not in meta.camera_keys:
            raise DatasetContractError(f"{where}: feature {key!r} is not an image/video stream")
        if key not in meta.video_keys:
            raise DatasetContractError(
                f"{where}: camera {key!r} is stored as images; expected a video stream"
            )


class FrameCachedDataset(LeRobotDataset):
    """LeRobotDataset that returns only `camera_keys`, decoded once into memory (uint8)."""

    def __init__(self, repo_id: str, root: str | Path, camera_keys: list[str], **kwargs):
        super().__init__(repo_id, root=root, **kwargs)
        # lerobot 0.6 reads through a DatasetReader: swap in ours, same settings, same indexing.
        self.reader = _FrameCachedReader(
            camera_keys,
            meta=self.meta,
            root=self.root,
            episodes=self.episodes,
            tolerance_s=self.tolerance_s,
            video_backend=self._video_backend,
            delta_timestamps=self.delta_timestamps,
            image_transforms=self.image_transforms,
        )
        self.reader.load_and_activate()
        self.reader.cache()

    def image_stats(self) -> dict[str, dict[str, np.ndarray]]:
        return self.reader.image_stats()

    def with_quantiles(self, stats: dict, keys: tuple[str, ...] = (OBS_STATE, ACTION)) -> dict:
        """`stats` with the quantiles lerobot's QUANTILES / QUANTILE10 normalisers read (q01, q10,
        q50, q90, q99) added for `keys` where missing, measured on the frames trained on."""
        out = dict(stats)
        for key in keys:
            have = dict(out.get(key) or {})
            missing = [q for q in QUANTILES if q not in have]
            if not missing:
                continue
            values = self.reader.column(key).astype(np.float64)
            for q in missing:
                have[q] = np.quantile(values, QUANTILES[q], axis=0).astype(np.float32)
            out[key] = have
        return out


# lerobot's quantile statistics (names as in its stats files).
QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
# Each normaliser's spread: (low, high) statistics, widened together around their middle.
_SPREADS = (("min", "max"), ("q01", "q99"), ("q10", "q90"))


def floor_spread(stats: dict, floor: float, features: dict,
                 keys: tuple[str, ...] = (OBS_STATE, ACTION)) -> tuple[dict, dict[str, list[str]]]:
    """``stats`` with every spread of ``keys`` at least ``floor`` (dataset units): a standard
    deviation below it becomes ``floor``; a (min, max), (q01, q99) or (q10, q90) pair narrower
    than ``2 * floor`` is widened to it around its middle. Whichever normaliser a policy uses
    (mean/std, min/max, quantiles), a near-constant feature then maps a change of ``floor`` to
    about one unit, not thousands. Returns the new statistics and, per key, the names of the
    features floored (``features``: the dataset's, as its metadata lists them)."""
    out, floored = dict(stats), {}
    for key in keys:
        if key not in out or floor <= 0:
            continue
        have = {k: np.asarray(v, dtype=np.float64) for k, v in out[key].items()}
        width = int(np.size(have.get("mean", have.get("std", have.get("min")))))
        names = features.get(key, {}).get("names") or [f"{key}[{i}]" for i in range(width)]
        narrow = np.zeros(width, dtype=bool)
        if "std" in have:
            narrow |= have["std"] < floor
            have["std"] = np.maximum(have["std"], floor)
        for low, high in _SPREADS:
            if low in have and high in have:
                middle, half = (have[low] + have[high]) / 2, (have[high] - have[low]) / 2
                small = half < floor
                narrow |= small
                have[low] = np.where(small, middle - floor, have[low])
                have[high] = np.where(small, middle + floor, have[high])
        out[key] = {k: v.astype(np.asarray(out[key][k]).dtype) for k, v in have.items()}
        if narrow.any():
            floored[key] = [name for name, low in zip(names, narrow) if low]
    return out, floored


class _FrameCachedReader(DatasetReader):
    """lerobot's reader with the video and numeric-column queries served from memory."""

    def __init__(self, camera_keys: list[str], **kwargs):
        super().__init__(**kwargs)
        self.camera_keys_used = list(camera_keys)
        # (video file path) -> (frame times [s], frames uint8 (N, C, H, W))
        self._decoded: dict[Path, tuple[np.ndarray, torch.Tensor]] = {}
        # (episode, camera) -> (video file, start time of the episode in that file)
        self._video_span: dict[tuple[int, str], tuple[Path, float]] = {}
        self._columns: dict[str, torch.Tensor] = {}

    def cache(self) -> None:
        meta = self._meta
        episodes = self.episodes if self.episodes is not None else range(meta.total_episodes)
        for ep_idx in episodes:
            ep = meta.episodes[ep_idx]
            for key in self.camera_keys_used:
                path = self.root / meta.get_video_file_path(ep_idx, key)
                self._video_span[(ep_idx, key)] = (path, float(ep[f"videos/{key}/from_timestamp"]))
                if path not in self._decoded:
                    self._decoded[path] = _decode_all_frames(path)
        # Numeric columns queried through delta timestamps (action chunk, state history), held as
        # tensors: row-wise Arrow access costs milliseconds per sample.
        for key in self.delta_indices or {}:
            if key not in meta.video_keys:
                self._columns[key] = torch.from_numpy(np.stack(self.hf_dataset.with_format("numpy")[key]))

        self._cache_rows()

    def _cache_rows(self) -> None:
        """Every row of the (episode-filtered) table as tensors, with what `get_item` looks up per
        sample (episode bounds, task names): read through Arrow once, not per sample. Only where
        lerobot's `get_item` would do nothing else (no image transform, no depth, no camera with
        delta timestamps); otherwise the stock path serves the samples."""
        meta = self._meta
        self._rows = None
        if (self._image_transforms is not None or self._image_depth_units or meta.depth_keys
                or any(key in meta.video_keys for key in self.delta_indices or {})):
            return
        columns = self.hf_dataset[:]  # lerobot's torch transform, applied to whole columns
        n = len(self.hf_dataset)
        self._rows = [{key: values[i] for key, values in columns.items()} for i in range(n)]
        episodes = meta.episodes
        self._episode_bounds = {
            int(ep): (int(start), int(end))
            for ep, start, end in zip(episodes["episode_index"], episodes["dataset_from_index"],
                                      episodes["dataset_to_index"])
        }
        self._task_names = list(meta.tasks.index)

    def get_item(self, idx) -> dict:
        """lerobot's `get_item` (same keys, values and dtypes) from the cached rows."""
        if self._rows is None:
            return super().get_item(idx)
        # Fresh tensors, as the stock path returns: nothing downstream can write into the cache.
        item = {key: value.clone() if isinstance(value, torch.Tensor) else value
                for key, value in self._rows[idx].items()}
        ep_idx = int(item["episode_index"])
        if self.delta_indices is not None:
            query_indices, padding = self._get_query_indices(int(item["index"]), ep_idx)
            item = {**item, **padding, **self._query_hf_dataset(query_indices)}
        if self._meta.video_keys:
            current_ts = float(item["timestamp"])
            now = {key: [current_ts] for key in self._meta.video_keys}
            item = {**self._query_videos(now, ep_idx), **item}
        item["task"] = self._task_names[int(item["task_index"])]
        return item

    def _get_query_indices(self, abs_idx: int, ep_idx: int) -> tuple[dict[str, list[int]], dict[str, torch.Tensor]]:
        """lerobot's, with the episode's bounds from the cache (its own reads the episodes table)."""
        if self._rows is None:
            return super()._get_query_indices(abs_idx, ep_idx)
        ep_start, ep_end = self._episode_bounds[ep_idx]
        deltas = self.delta_indices.items()
        query_indices = {key: [max(ep_start, min(ep_end - 1, abs_idx + d)) for d in steps]
                         for key, steps in deltas}
        padding = {f"{key}_is_pad": torch.BoolTensor([not ep_start <= abs_idx + d < ep_end for d in steps])
                   for key, steps in deltas}
        return query_indices, padding

    def column(self, key: str) -> np.ndarray:
        """A numeric column over the selected episodes' frames, (N, D)."""
        if key in self._columns:
            # Held for delta-timestamp queries; same rows as the dataset.
            return self._columns[key].numpy()
        return np.stack(self.hf_dataset.with_format("numpy")[key])

    def image_stats(self) -> dict[str, dict[str, np.ndarray]]:
        """Per-channel mean/std/min/max in [0, 1] of every cached camera, shaped (3, 1, 1)."""
        stats = {}
        for key in self.camera_keys_used:
            paths = sorted({path for (_, k), (path, _) in self._video_span.items() if k == key})
            frames = torch.cat([self._decoded[p][1] for p in paths])
            frames = frames[:: max(1, len(frames) // 256)]  # a few hundred frames pin the moments down
            pixels = frames.permute(1, 0, 2, 3).reshape(3, -1).float() / 255.0
            stats[key] = {
                "mean": pixels.mean(dim=1).numpy().reshape(3, 1, 1),
                "std": pixels.std(dim=1).clamp_min(1e-3).numpy().reshape(3, 1, 1),
                "min": pixels.min(dim=1).values.numpy().reshape(3, 1, 1),
                "max": pixels.max(dim=1).values.numpy().reshape(3, 1, 1),
            }
        return stats

    def _query_videos(self, query_timestamps: dict[str, list[float]], ep_idx: int) -> dict[str, torch.Tensor]:
        item = {}
        for key in self.camera_keys_used:
            path, from_ts = self._video_span[(ep_idx, key)]
            times, frames = self._decoded[path]
            # Episodes share one video file; their frames start at `from_timestamp`.
            wanted = from_ts + np.asarray(query_timestamps[key])
            idx = np.abs(times[None, :] - wanted[:, None]).argmin(axis=1)
            err = np.abs(times[idx] - wanted)
            if (err > self._tolerance_s).any():
                raise DataError(
                    f"camera {key!r} episode {ep_idx}: no video frame within {self._tolerance_s}s of "
                    f"t={wanted[err.argmax()]:.4f}s in {path}"
                )
            # Same layout as lerobot's decoders: float32 in [0, 1], channel first.
            item[key] = (frames[idx].float() / 255.0).squeeze(0)
        return item

    def _query_hf_dataset(self, query_indices: dict[str, list[int]]) -> dict:
        result = {}
        for key, q_idx in query_indices.items():
            if key in self._meta.video_keys:
                continue
            to_rel = self._absolute_to_relative_idx
            rel = q_idx if to_rel is None else [to_rel[i] for i in q_idx]
            result[key] = self._columns[key][rel]
        return result


def _decode_all_frames(path: Path) -> tuple[np.ndarray, torch.Tensor]:
    import av

    times, frames = [], []
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        for frame in container.decode(stream):
            times.append(float(frame.time))
            frames.append(frame.to_ndarray(format="rgb24"))
    if not frames:
        raise DataError(f"video {path} has no decodable frames")
    stacked = torch.from_numpy(np.stack(frames)).permute(0, 3, 1, 2).contiguous()
    return np.asarray(times, dtype=np.float64), stacked


def select_episodes(meta: LeRobotDatasetMetadata, fraction: float, allowed: list[int] | None = None) -> list[int] | None:
    """The first `fraction` of each task's episodes (at least one per task) among `allowed` (all
    when None); None keeps every episode of the dataset.

    Per task, so a smaller share still covers every task of a multi-task dataset.
    """
    if fraction >= 1.0 and allowed is None:
        return None
    known = set(range(meta.total_episodes))
    if allowed is not None and not set(allowed) <= known:
        raise DatasetContractError(
            f"dataset {meta.repo_id!r} at {meta.root} has no episodes {sorted(set(allowed) - known)[:10]} "
            "that the episode index lists; was the index made from another dataset?"
        )
    by_task: dict[str, list[int]] = {}
    for ep_idx in sorted(known if allowed is None else set(allowed)):
        tasks = meta.episodes[ep_idx]["tasks"]
        by_task.setdefault(str(tasks[0] if len(tasks) else ""), []).append(ep_idx)
    if not by_task:
        raise DatasetContractError(f"dataset {meta.repo_id!r} at {meta.root}: no episode to train on")
    keep = [ep for eps in by_task.values() for ep in eps[: max(1, math.ceil(min(fraction, 1.0) * len(eps)))]]
    return sorted(keep)


def make_training_dataset(
    dataset_root: str | Path,
    repo_id: str,
    meta: LeRobotDatasetMetadata,
    lerobot_cfg,
    image_keys: list[str],
    episodes: list[int] | None = None,
) -> FrameCachedDataset:
    """Dataset with the policy's delta timestamps (action chunk, observation history).

    `episodes` restricts it to those episode indices (all when None).
    """
    from lerobot.datasets.factory import resolve_delta_timestamps

    delta = resolve_delta_timestamps(lerobot_cfg, meta) or {}
    used = {OBS_STATE, ACTION, *image_keys}
    delta = {k: v for k, v in delta.items() if k in used} or None
    return FrameCachedDataset(
        repo_id,
        root=dataset_root,
        camera_keys=image_keys,
        delta_timestamps=delta,
        video_backend="pyav",
        episodes=episodes,
    )
