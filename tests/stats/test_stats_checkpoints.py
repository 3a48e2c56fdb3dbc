"""checkpoint_metrics: per-checkpoint fits and metrics, averages and last values."""

import numpy as np
import pandas as pd
import pytest

from r2s_eval.stats import (
    CheckpointMetrics,
    bootstrap_bradley_terry,
    bt_ci_width,
    checkpoint_metrics,
    fit_bradley_terry,
    mmrv,
    spearman,
)


def nested_wins(truth, checkpoints, seed):
    """Win counts at nested checkpoints: the first n comparisons of every pair."""
    rng = np.random.default_rng(seed)
    P = len(truth)
    outcomes = {}
    for i in range(P):
        for j in range(i + 1, P):
            outcomes[i, j] = rng.random(max(checkpoints)) < truth[i] / (truth[i] + truth[j])
    wins = np.zeros((len(checkpoints), P, P))
    for c, n in enumerate(checkpoints):
        for (i, j), won in outcomes.items():
            wins[c, i, j] = won[:n].sum()
            wins[c, j, i] = n - wins[c, i, j]
    return wins


@pytest.fixture(scope="module")
def result():
    truth = np.array([0.3, 0.27, 0.2, 0.13, 0.1])
    wins = nested_wins(truth, [100, 200, 400], seed=3)
    reference = np.array([0.80, 0.78, 0.55, 0.40, 0.20])
    metrics = checkpoint_metrics(
        wins, reference, n_boot=300, seed=5, names=list("abcde"), checkpoints=[100, 200, 400]
    )
    return wins, reference, metrics


def test_per_checkpoint_values_match_the_building_blocks(result):
    wins, reference, m = result
    assert isinstance(m, CheckpointMetrics)
    assert m.strengths.shape == m.scores.shape == m.ci_lower.shape == (3, 5)
    assert m.boot_strengths.shape == (3, 300, 5)
    np.testing.assert_allclose(m.strengths, [fit_bradley_terry(w) for w in wins], atol=1e-6)
    np.testing.assert_allclose(m.scores, 100 * m.strengths)
    np.testing.assert_array_equal(m.boot_strengths, bootstrap_bradley_terry(wins, n_boot=300, seed=5))
    assert np.all(m.ci_lower <= m.ci_upper)
    assert list(m.per_checkpoint.index) == [100, 200, 400]
    assert list(m.per_checkpoint.columns) == ["ci_width", "spearman", "pearson", "mmrv"]
    np.testing.assert_allclose(m.per_checkpoint["ci_width"], bt_ci_width(m.boot_strengths))
    for c in range(3):
        assert m.per_checkpoint["spearman"].iloc[c] == pytest.approx(spearman(m.scores[c], reference))
        assert m.per_checkpoint["mmrv"].iloc[c] == pytest.approx(mmrv(m.scores[c], reference))
    # More comparisons, narrower intervals.
    assert m.per_checkpoint["ci_width"].is_monotonic_decreasing


def test_average_and_last(result):
    _, _, m = result
    pd.testing.assert_series_equal(m.average, m.per_checkpoint.mean(axis=0), check_names=False)
    pd.testing.assert_series_equal(m.last, m.per_checkpoint.loc[400], check_names=False)


def test_policy_table(result):
    _, _, m = result
    table = m.policy_table()
    assert len(table) == 15
    assert list(table.columns) == ["checkpoint", "policy", "strength", "score", "ci_lower", "ci_upper", "ci_aware_rank"]
    last = table[table.checkpoint == 400].set_index("policy")
    np.testing.assert_allclose(last["score"], m.scores[-1])
    assert last["ci_aware_rank"].min() == 1


def test_input_checks():
    wins = np.array([[0, 3], [2, 0]])
    with pytest.raises(ValueError, match="one value per policy"):
        checkpoint_metrics(wins, [0.5, 0.4, 0.3], n_boot=10)
    single = checkpoint_metrics(wins, [0.6, 0.4], n_boot=10)
    assert single.per_checkpoint.shape == (1, 4)
