"""The training dataset's cached rows give what lerobot's own sample lookup gives, sample for sample."""

from __future__ import annotations

import pytest
import torch

from tests.helpers.datasets import build_dataset

pytestmark = pytest.mark.timeout(300)

HEAD = "observation.images.head_left"


@pytest.mark.parametrize("episodes", [None, [0, 2]])  # the whole dataset, and a subset (relative indices)
def test_cached_rows_give_lerobots_samples(tmp_path, episodes):
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    from r2s_eval.policies.data import FrameCachedDataset

    root = build_dataset(tmp_path / "ds", n_episodes=3, n_steps=12, cameras=(HEAD, "observation.images.wrist_left"))
    meta = LeRobotDatasetMetadata("test/synthetic_bimanual", root=root)
    # An action chunk and a state history: padded at both ends of every episode.
    delta = {"action": [i / meta.fps for i in range(5)], "observation.state": [-1 / meta.fps, 0.0]}
    dataset = FrameCachedDataset("test/synthetic_bimanual", root=root, camera_keys=[HEAD],
                                 delta_timestamps=delta, video_backend="pyav", episodes=episodes)
    assert dataset.reader._rows is not None  # the cached path is the one under test
    fast = [dataset[i] for i in range(len(dataset))]
    dataset.reader._rows = None  # lerobot's get_item, over the same decoded frames
    stock = [dataset[i] for i in range(len(dataset))]
    assert len(fast) == len(stock) == (36 if episodes is None else 24)
    for i, (got, want) in enumerate(zip(fast, stock)):
        assert list(got) == list(want), i
        for key, value in want.items():
            if isinstance(value, torch.Tensor):
                assert got[key].dtype == value.dtype and torch.equal(got[key], value), (i, key)
            else:
                assert got[key] == value, (i, key)
    assert any(s["action_is_pad"].any() for s in stock) and any(s["observation.state_is_pad"].any() for s in stock)
    # What a sample holds is a copy: writing into it leaves the next sample as it was.
    fast_again = FrameCachedDataset("test/synthetic_bimanual", root=root, camera_keys=[HEAD],
                                    delta_timestamps=delta, video_backend="pyav", episodes=episodes)
    fast_again[0]["observation.state"] += 1.0
    fast_again[0]["timestamp"] += 1.0
    assert torch.equal(fast_again[0]["observation.state"], stock[0]["observation.state"])
    assert torch.equal(fast_again[0]["timestamp"], stock[0]["timestamp"])
