"""Reference performance: mean of the per-task success rates, and its trial-resampling bootstrap."""

import numpy as np
import pytest

from r2s_eval.stats import bootstrap_task_mean_success, task_mean_success


def test_mean_of_task_rates_not_pooled_trials():
    successes = np.array([[9, 1], [5, 0]])
    trials = np.array([[10, 2], [10, 0]])  # policy 1 has no trials on task 1
    # Policy 0: (0.9 + 0.5) / 2 = 0.7, where pooling would give 10 / 12.
    np.testing.assert_allclose(task_mean_success(successes, trials), [0.7, 0.5])
    with pytest.raises(ValueError, match="no trials on any task"):
        task_mean_success([[0, 0]], [[0, 0]])
    with pytest.raises(ValueError, match="successes <= trials"):
        task_mean_success([[3]], [[2]])


def test_bootstrap_resamples_trials_within_each_task():
    successes = np.array([[8, 3, 0], [2, 2, 0]])
    trials = np.array([[10, 4, 6], [10, 4, 0]])
    boot = bootstrap_task_mean_success(successes, trials, n_boot=20_000, seed=3)
    assert boot.shape == (20_000, 2)
    # Per-task rates are whole counts over the task's trials, so every replicate of policy 0
    # is a mean of k0/10, k1/4 and k2/6; a task with no successes stays at zero.
    grid = {(a / 10 + b / 4 + 0.0) / 3 for a in range(11) for b in range(5)}
    assert all(any(abs(v - g) < 1e-12 for g in grid) for v in np.unique(boot[:, 0]))
    # Mean and variance of a mean of independent binomial rates.
    p = successes / np.maximum(trials, 1)
    var0 = (p[0] * (1 - p[0]) / trials[0]).sum() / 9
    var1 = (p[1, :2] * (1 - p[1, :2]) / trials[1, :2]).sum() / 4
    np.testing.assert_allclose(boot.mean(axis=0), task_mean_success(successes, trials), atol=0.003)
    np.testing.assert_allclose(boot.var(axis=0), [var0, var1], rtol=0.05)
    # Seeded: same seed, same draws; another seed, others.
    np.testing.assert_array_equal(boot[:100], bootstrap_task_mean_success(successes, trials, 100, seed=3)[:100])
    assert not np.array_equal(boot[:100], bootstrap_task_mean_success(successes, trials, 100, seed=4))
