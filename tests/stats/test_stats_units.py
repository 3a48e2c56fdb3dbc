"""Unit bootstrap: grouping comparisons into units, exact stratified resampling, refits, widths."""

import warnings

import numpy as np
import pytest

from r2s_eval.stats import (
    bootstrap_bradley_terry,
    bt_ci_width,
    comparison_units,
    fit_bradley_terry,
    unit_bootstrap_bradley_terry,
    unit_bootstrap_wins,
)
from r2s_eval.stats.units import BLOCK, UNIT_KEY, tagged_seed


def design(P, tasks, inits, n, rng, spread=1.5, noise=0.0, theta=None):
    """Comparisons of every pair: position k is task k % tasks at a random init; every (pair,
    task, init) is one rollout pair whose latent preference is drawn once (logit spread
    ``spread`` around the strength difference), so repeats of it agree more than fresh
    comparisons would. ``noise``: chance that a repeat's verdict is a coin flip."""
    theta = np.linspace(0.8, -0.8, P) if theta is None else np.asarray(theta)
    rows = []
    for a in range(P):
        for b in range(a + 1, P):
            latent = {}
            for k in range(n):
                t, init = k % tasks, int(rng.integers(inits))
                if (t, init) not in latent:
                    latent[t, init] = 1 / (1 + np.exp(-(theta[a] - theta[b] + rng.normal(0, spread))))
                p = latent[t, init] if rng.random() >= noise else 0.5
                # Alternate which side is named first, so orientation is exercised.
                i, j = (a, b) if k % 2 else (b, a)
                won_a = rng.random() < p
                rows.append((i, j, won_a if i == a else not won_a, init, t, k))
    i, j, won, init, task, pos = map(np.array, zip(*rows))
    return dict(policy_i=i, policy_j=j, i_won=won, unit=init, stratum=task, position=pos)


def brute_force_wins(units, n_boot, seed):
    """The documented resampling, one slot at a time: (C, n_boot, P, P)."""
    P, C = units.n_policies, len(units.checkpoints)
    I, J = np.triu_indices(P, 1)
    sizes = units.stratum_size
    starts = units.stratum_start
    out = np.zeros((C, n_boot, P, P))
    for q, first in enumerate(range(0, n_boot, BLOCK)):
        rows = min(BLOCK, n_boot - first)
        V = np.random.default_rng(tagged_seed(seed, UNIT_KEY, q)).random((rows, units.n_units))
        for r in range(rows):
            for c in range(C):
                for s, start in enumerate(starts):
                    m = sizes[c, s]
                    for slot in range(m):
                        u = start + int(V[r, start + slot] * m)
                        k = units.pair[u]
                        out[c, first + r, I[k], J[k]] += units.wins_ij[c, u]
                        out[c, first + r, J[k], I[k]] += units.wins_ji[c, u]
    return out


def test_units_by_hand():
    # Pair (0, 1): task x has inits 5 (seen at positions 0, 2) and 7 (position 3); task y init 5
    # (position 1) is another unit. Pair (0, 2) with policy 2 named first: one unit.
    units = comparison_units(
        [0, 1, 0, 1, 2, 2], [1, 0, 1, 0, 0, 0], [True, True, False, True, True, False],
        [5, 5, 5, 7, 1, 1], n_policies=3, stratum=["x", "y", "x", "x", "x", "x"],
        position=[0, 1, 2, 3, 0, 1], checkpoints=[2, 4],
    )
    assert units.n_units == 4
    assert units.pair.tolist() == [0, 0, 0, 1] and units.stratum.tolist() == [0, 0, 1, 2]
    assert units.rank.tolist() == [0, 1, 0, 0]  # x: init 5 first, then init 7
    # Unit (0,1,x,5): positions 0 (0 won) and 2 (1 won); (0,1,x,7): 1 won; (0,1,y,5): 1 won;
    # (0,2,x,1): 2 won at position 0, 0 won at position 1.
    np.testing.assert_array_equal(units.wins_ij, [[1, 0, 0, 1], [1, 0, 0, 1]])
    np.testing.assert_array_equal(units.wins_ji, [[0, 0, 1, 1], [1, 1, 1, 1]])
    np.testing.assert_array_equal(units.stratum_size, [[1, 1, 1], [2, 1, 1]])
    np.testing.assert_array_equal(units.units_per_pair(), [[2, 1, 0], [3, 1, 0]])
    np.testing.assert_array_equal(units.wins()[1], [[0, 1, 1], [3, 0, 0], [1, 0, 0]])
    with pytest.raises(ValueError, match="two different policies"):
        comparison_units([0], [0], [True], [1], n_policies=2)


def test_resampling_matches_brute_force_and_refits_match_mm():
    rng = np.random.default_rng(4)
    units = comparison_units(**design(3, tasks=3, inits=4, n=36, rng=rng), n_policies=3, checkpoints=[12, 24, 36])
    n_boot = BLOCK + 11  # two blocks, the second one short
    wins = unit_bootstrap_wins(units, n_boot=n_boot, seed=[3, 1])
    np.testing.assert_array_equal(wins, brute_force_wins(units, n_boot, [3, 1]))
    # Replicates keep each pair's units per task, so totals stay positive and the graph connected.
    assert np.all((wins + wins.transpose(0, 1, 3, 2))[:, :, ~np.eye(3, dtype=bool)] > 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # small replicates may sit at the boundary
        boot = unit_bootstrap_bradley_terry(units, n_boot=n_boot, seed=[3, 1])
        plain = np.array([[fit_bradley_terry(m) for m in reps] for reps in wins])
    np.testing.assert_allclose(boot, plain, atol=1e-6)


def test_resampled_counts_have_the_stratified_bootstrap_moments():
    # Per pair, sum over strata of m_s draws with replacement: mean = observed total,
    # variance = sum_s m_s * (population variance of the unit counts in s).
    rng = np.random.default_rng(7)
    units = comparison_units(**design(3, tasks=2, inits=5, n=60, rng=rng), n_policies=3)
    n_boot = 6000
    wins = unit_bootstrap_wins(units, n_boot=n_boot, seed=0)[0]
    I, J = np.triu_indices(3, 1)
    for k in range(3):
        mean, var = 0.0, 0.0
        for s in np.unique(units.stratum[units.pair == k]):
            x = units.wins_ij[0, units.stratum == s]
            mean += x.sum()
            var += x.size * x.var()
        draws = wins[:, I[k], J[k]]
        assert abs(draws.mean() - mean) < 5 * np.sqrt(var / n_boot)
        assert draws.var() == pytest.approx(var, rel=0.1)
        # Comparisons per pair vary (units differ in size) but every replicate has some.
        assert np.all(draws + wins[:, J[k], I[k]] > 0)


def test_checkpoints_reuse_the_same_draws():
    # The second half of each pair's sequence repeats the first exactly: same units, same
    # verdicts. Coupled replicates then have exactly twice the first checkpoint's wins.
    rng = np.random.default_rng(2)
    d = design(4, tasks=3, inits=3, n=30, rng=rng)
    twice = {key: np.concatenate([v, v + 30 if key == "position" else v]) for key, v in d.items()}
    units = comparison_units(**twice, n_policies=4, checkpoints=[30, 60])
    wins = unit_bootstrap_wins(units, n_boot=200, seed=5)
    np.testing.assert_array_equal(wins[1], 2 * wins[0])
    boot = unit_bootstrap_bradley_terry(units, n_boot=200, seed=5)
    np.testing.assert_allclose(boot[1], boot[0], atol=1e-6)


def test_deterministic_and_thread_invariant():
    rng = np.random.default_rng(1)
    units = comparison_units(**design(4, tasks=3, inits=5, n=60, rng=rng), n_policies=4, checkpoints=[30, 60])
    a = unit_bootstrap_bradley_terry(units, n_boot=300, seed=12)
    b = unit_bootstrap_bradley_terry(units, n_boot=300, seed=12, n_threads=2)
    c = unit_bootstrap_bradley_terry(units, n_boot=300, seed=13)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # More replicates extend the same stream: the first 300 do not change.
    np.testing.assert_array_equal(unit_bootstrap_bradley_terry(units, n_boot=400, seed=12)[:, :300], a)
    # A SeedSequence is not consumed.
    seq = np.random.SeedSequence(12)
    np.testing.assert_array_equal(unit_bootstrap_bradley_terry(units, n_boot=300, seed=seq), a)


def test_every_comparison_its_own_unit_matches_the_binomial_width():
    # With one comparison per unit and one stratum per pair, resampling units is drawing each
    # pair's n comparisons with replacement: wins ~ Binomial(n, observed rate), the binomial
    # bootstrap exactly, up to Monte Carlo error.
    rng = np.random.default_rng(11)
    d = design(5, tasks=1, inits=10**9, n=300, rng=rng, spread=0.0)
    d["unit"] = np.arange(len(d["unit"]))  # every comparison its own rollout pair
    units = comparison_units(**d, n_policies=5, checkpoints=[100, 300])
    unit_w = bt_ci_width(unit_bootstrap_bradley_terry(units, n_boot=2000, seed=0), level=0.95)
    binom_w = bt_ci_width(bootstrap_bradley_terry(units.wins(), n_boot=2000, seed=0), level=0.95)
    np.testing.assert_allclose(unit_w / binom_w, 1.0, atol=0.06)
    # Stratified by task with the same rate in every task: still the binomial width.
    d["stratum"] = d["position"] % 4
    strata = comparison_units(**d, n_policies=5, checkpoints=[100, 300])
    strat_w = bt_ci_width(unit_bootstrap_bradley_terry(strata, n_boot=2000, seed=0), level=0.95)
    np.testing.assert_allclose(strat_w / binom_w, 1.0, atol=0.06)


def test_repeated_rollout_pairs_widen_the_intervals():
    # 400 comparisons per pair from 7 tasks x 3 inits: each rollout pair is judged ~19 times
    # with a strongly shared latent preference. The binomial bootstrap counts 400 independent
    # verdicts; the unit bootstrap sees 21 rollout pairs.
    rng = np.random.default_rng(5)
    units = comparison_units(**design(4, tasks=7, inits=3, n=400, rng=rng, spread=2.5), n_policies=4,
                             checkpoints=[400])
    assert units.units_per_pair().max() <= 21
    unit_w = bt_ci_width(unit_bootstrap_bradley_terry(units, n_boot=1000, seed=0), level=0.95)
    binom_w = bt_ci_width(bootstrap_bradley_terry(units.wins(), n_boot=1000, seed=0), level=0.95)
    assert unit_w > 2.0 * binom_w, (unit_w, binom_w)


def test_single_policy_and_input_checks():
    units = comparison_units([0, 1], [1, 0], [True, True], [0, 0], n_policies=2)
    assert unit_bootstrap_bradley_terry(units, n_boot=3).shape == (1, 3, 2)
    with pytest.raises(ValueError, match="n_boot"):
        unit_bootstrap_bradley_terry(units, n_boot=0)
    with pytest.raises(ValueError, match="policy indices"):
        comparison_units([0], [2], [True], [0], n_policies=2)
    with pytest.raises(ValueError, match="checkpoints"):
        comparison_units([0], [1], [True], [0], n_policies=2, checkpoints=[0])
