"""LeRobot's running image statistics from value counts: the numbers LeRobot's own update gives."""

from __future__ import annotations

import numpy as np
import pytest
from lerobot.datasets.compute_stats import RunningQuantileStats

from r2s_eval.data.image_stats import counted_update, lerobot_update, use_counted_image_stats


def _frames(seed: int) -> list[np.ndarray]:
    """(H*W, 3) uint8 pixels whose range widens over the frames (the histograms are re-binned)."""
    rng = np.random.default_rng(seed)
    frames = []
    for spread in (5, 5, 20, 60, 60, 127):
        pixels = rng.normal(128, spread, size=(64 * 48, 3)).round().clip(0, 255).astype(np.uint8)
        frames.append(pixels)
    frames.append(np.full((64 * 48, 3), 200, dtype=np.uint8))  # one value per channel
    return frames


@pytest.mark.parametrize("seed", [0, 1])
def test_counted_statistics_equal_lerobots(seed):
    stock, counted = RunningQuantileStats(), RunningQuantileStats()
    for frame in _frames(seed):
        lerobot_update()(stock, frame)
        counted_update(counted, frame)
    want, got = stock.get_statistics(), counted.get_statistics()
    assert set(got) == set(want)
    for key in ("min", "max", "mean", "count", "q01", "q10", "q50", "q90", "q99"):
        assert got[key].dtype == want[key].dtype and np.array_equal(got[key], want[key]), key
    for got_hist, want_hist in zip(counted._histograms, stock._histograms):
        assert np.array_equal(got_hist, want_hist)
    # The mean of squares: summed exactly here, in float32 by LeRobot (off by about 5e-5 of the
    # standard deviation at this spread); ours is at least as close to the exact value.
    exact = np.concatenate(_frames(seed)).astype(np.float64).std(axis=0)
    np.testing.assert_allclose(got["std"], want["std"], rtol=2e-4)
    assert (np.abs(got["std"] - exact) <= np.abs(want["std"] - exact) + 1e-6 * exact).all()


def test_other_batches_go_through_lerobots_update():
    use_counted_image_stats()
    use_counted_image_stats()  # twice: still one layer
    assert RunningQuantileStats.update is counted_update and lerobot_update() is not counted_update
    states = np.random.default_rng(2).normal(size=(40, 14)).astype(np.float32)
    stock, routed = RunningQuantileStats(), RunningQuantileStats()
    lerobot_update()(stock, states)
    routed.update(states)
    for key, value in stock.get_statistics().items():
        assert np.array_equal(routed.get_statistics()[key], value), key
