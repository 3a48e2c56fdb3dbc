"""checkpoint_metrics: per-checkpoint fits and metrics, averages and last values."""

import numpy as np
import pandas as pd
import pytest

from r2s_eval.stats import (
    CheckpointMetrics,
    bootstrap_bradley_terry,
    bt_ci_width,
    checkpoint_metrics,
    comparison_units,
    fit_bradley_terry,
    mmrv,
    spearman,
    unit_bootstrap_bradley_terry,
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
        wins, reference, n_boot=300, seed=5, level=0.95, names=list("abcde"), checkpoints=[100, 200, 400]
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
    np.testing.assert_allclose(m.per_checkpoint["ci_width"], bt_ci_width(m.boot_strengths, level=0.95))
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
        checkpoint_metrics(wins, [0.5, 0.4, 0.3], n_boot=10, level=0.95)
    single = checkpoint_metrics(wins, [0.6, 0.4], n_boot=10, level=0.95)
    assert single.per_checkpoint.shape == (1, 4)


@pytest.fixture(scope="module")
def unit_result():
    """Three tasks x four inits per pair, 120 comparisons per pair, nested at 40/80/120."""
    rng = np.random.default_rng(8)
    theta = np.log([0.35, 0.3, 0.2, 0.15])
    rows = []
    for a in range(4):
        for b in range(a + 1, 4):
            latent = {}
            for k in range(120):
                key = (k % 3, int(rng.integers(4)))
                latent.setdefault(key, 1 / (1 + np.exp(-(theta[a] - theta[b] + rng.normal(0, 1.5)))))
                rows.append((a, b, rng.random() < latent[key], key[1], key[0], k))
    i, j, won, init, task, pos = map(np.array, zip(*rows))
    units = comparison_units(i, j, won, init, n_policies=4, stratum=task, position=pos, checkpoints=[40, 80, 120])
    reference = np.array([0.7, 0.5, 0.45, 0.2])
    reference_boot = np.random.default_rng(0).normal(reference, 0.08, size=(400, 4))
    metrics = checkpoint_metrics(units, reference, n_boot=400, seed=2, level=0.95, names=list("abcd"),
                                 reference_boot=reference_boot)
    return units, reference, reference_boot, metrics


def test_units_give_both_intervals_and_show_the_unit_one(unit_result):
    units, reference, _, m = unit_result
    assert m.interval == "unit" and set(m.boot_by_interval) == {"unit", "binomial"}
    np.testing.assert_array_equal(m.checkpoints, [40, 80, 120])
    np.testing.assert_array_equal(m.boot_strengths, unit_bootstrap_bradley_terry(units, n_boot=400, seed=2))
    binomial_boot = bootstrap_bradley_terry(units.wins(), n_boot=400, seed=2)
    np.testing.assert_array_equal(m.boot_by_interval["binomial"], binomial_boot)
    np.testing.assert_allclose(m.per_checkpoint["ci_width"], bt_ci_width(m.boot_strengths, level=0.95))
    np.testing.assert_allclose(m.ci_width_by_interval["unit"], m.per_checkpoint["ci_width"])
    np.testing.assert_allclose(m.ci_width_by_interval["binomial"], bt_ci_width(m.boot_by_interval["binomial"], level=0.95))
    # Repeated rollout pairs: the unit interval is the wider one at every checkpoint.
    assert (m.ci_width_by_interval["unit"] > m.ci_width_by_interval["binomial"]).all()
    binomial = checkpoint_metrics(units, reference, n_boot=400, seed=2, level=0.95, interval="binomial")
    np.testing.assert_allclose(binomial.per_checkpoint["ci_width"], m.ci_width_by_interval["binomial"])
    with pytest.raises(ValueError, match="ComparisonUnits"):
        checkpoint_metrics(units.wins(), reference, n_boot=10, level=0.95, interval="unit")
    with pytest.raises(ValueError, match="interval must be one of"):
        checkpoint_metrics(units, reference, n_boot=10, level=0.95, interval="poisson")


def test_metric_intervals_come_from_the_replicates(unit_result):
    _, reference, reference_boot, m = unit_result
    boot_scores = 100 * m.boot_strengths
    for c, label in enumerate(m.checkpoints):
        for name, fn in (("spearman", spearman), ("mmrv", mmrv)):
            judge_side = [fn(s, reference) for s in boot_scores[c]]
            both = [fn(s, r) for s, r in zip(boot_scores[c], reference_boot)]
            lo, hi = np.nanpercentile(judge_side, [2.5, 97.5])
            assert m.metric_ci.loc[label, f"{name}_low"] == pytest.approx(lo)
            assert m.metric_ci.loc[label, f"{name}_high"] == pytest.approx(hi)
            lo, hi = np.nanpercentile(both, [2.5, 97.5])
            assert m.metric_ci.loc[label, f"{name}_low_with_reference"] == pytest.approx(lo)
            assert m.metric_ci.loc[label, f"{name}_high_with_reference"] == pytest.approx(hi)
    # The reference's own uncertainty widens the Pearson interval.
    judge_width = m.metric_ci["pearson_high"] - m.metric_ci["pearson_low"]
    both_width = m.metric_ci["pearson_high_with_reference"] - m.metric_ci["pearson_low_with_reference"]
    assert (both_width > judge_width).all()
    # The unit bootstrap's replicates are coupled across checkpoints: the average has an interval.
    per_replicate = np.mean([[spearman(s, reference) for s in boot_scores[c]] for c in range(3)], axis=0)
    assert m.average_ci["spearman_low"] == pytest.approx(np.percentile(per_replicate, 2.5))
    binomial = checkpoint_metrics(unit_result[0], reference, n_boot=50, seed=2, level=0.95, interval="binomial")
    assert np.isnan(binomial.average_ci["spearman_low"])  # independent draws per checkpoint: none
