"""Bradley-Terry fitting: agreement with choix, MM semantics, bootstrap and errors."""

import warnings

import choix
import numpy as np
import pytest

from r2s_eval.errors import ConfigError, StatsError
from r2s_eval.stats import (
    DisconnectedComparisonsError,
    bootstrap_bradley_terry,
    bootstrap_wins,
    bt_ci_width,
    bt_confidence_intervals,
    bt_scores,
    comparison_groups,
    fit_bradley_terry,
    fit_bradley_terry_batch,
)

TOL = 1e-6


def choix_strengths(wins: np.ndarray, alpha: float = 0.0) -> np.ndarray:
    """Normalised exp(params) from choix's ILSR on the expanded (winner, loser) list."""
    i, j = np.nonzero(wins)
    data = [(a, b) for a, b, c in zip(i, j, wins[i, j].astype(int)) for _ in range(c)]
    params = choix.ilsr_pairwise(len(wins), data, alpha=alpha, max_iter=10_000, tol=1e-12)
    strengths = np.exp(params - params.max())
    return strengths / strengths.sum()


def simulate(strengths, counts, rng) -> np.ndarray:
    """Win matrix with counts[i, j] comparisons per pair (upper triangle used)."""
    b = np.asarray(strengths, dtype=float)
    P = len(b)
    wins = np.zeros((P, P))
    for i in range(P):
        for j in range(i + 1, P):
            n = int(counts[i, j])
            wins[i, j] = rng.binomial(n, b[i] / (b[i] + b[j]))
            wins[j, i] = n - wins[i, j]
    return wins


def full_counts(P, n):
    return np.full((P, P), n)


def test_mm_fixed_point_by_hand():
    # 0 beat 1 twice and lost once: b0 / (b0 + b1) = 2/3, so b = (2/3, 1/3).
    wins = np.array([[0, 2], [1, 0]])
    np.testing.assert_allclose(fit_bradley_terry(wins), [2 / 3, 1 / 3], atol=1e-9)
    np.testing.assert_allclose(bt_scores(fit_bradley_terry(wins)), [200 / 3, 100 / 3], atol=1e-7)


@pytest.mark.parametrize("seed", range(6))
def test_random_matrices_agree_with_choix(seed):
    rng = np.random.default_rng(seed)
    P = int(rng.integers(2, 9))
    counts = rng.integers(5, 80, size=(P, P))
    wins = simulate(rng.dirichlet(np.ones(P)), counts, rng)
    reference = choix_strengths(wins)
    mm = fit_bradley_terry(wins)
    np.testing.assert_allclose(mm.sum(), 1.0, atol=1e-12)
    np.testing.assert_allclose(mm, reference, atol=TOL)
    np.testing.assert_allclose(fit_bradley_terry_batch(wins), reference, atol=TOL)


def _near_ties():
    # Every pair split 500:500 except two neighbours off by one comparison.
    wins = np.full((5, 5), 500.0)
    np.fill_diagonal(wins, 0)
    wins[0, 1], wins[1, 0] = 501, 499
    wins[3, 4], wins[4, 3] = 499, 501
    return wins


def _lopsided():
    # Strengths over three orders of magnitude; every pair still went both ways.
    b = np.array([1.0, 0.2, 0.03, 0.005, 0.001])
    n = 400
    wins = np.zeros((5, 5))
    for i in range(5):
        for j in range(5):
            if i != j:
                wins[i, j] = max(1, round(n * b[i] / (b[i] + b[j])))
    return wins


def _sparse_chain():
    # A chain 0-1-2-3-4-5 plus one chord 0-5: connected, most pairs never compared.
    P = 6
    wins = np.zeros((P, P))
    for i, (a, b) in enumerate([(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (0, 5)]):
        wins[a, b], wins[b, a] = 12 + i, 9 + 2 * i
    return wins


def _large_counts():
    rng = np.random.default_rng(7)
    return simulate([0.5, 0.3, 0.2], full_counts(3, 40_000), rng)


@pytest.mark.parametrize(
    "make", [_near_ties, _lopsided, _sparse_chain, _large_counts], ids=lambda f: f.__name__[1:]
)
def test_adversarial_matrices_agree_with_choix(make):
    wins = make()
    reference = choix_strengths(wins)
    np.testing.assert_allclose(fit_bradley_terry(wins), reference, atol=TOL)
    np.testing.assert_allclose(fit_bradley_terry_batch(wins), reference, atol=TOL)


def test_never_winning_policy_gets_zero_strength():
    rng = np.random.default_rng(3)
    wins = simulate([0.4, 0.3, 0.2, 0.1], full_counts(4, 30), rng)
    wins[2, :] = 0  # policy 2 lost every comparison
    mm = fit_bradley_terry(wins)
    assert np.all(np.isfinite(mm))
    assert mm[2] == 0.0
    np.testing.assert_allclose(mm.sum(), 1.0, atol=1e-12)
    reference = choix_strengths(wins, alpha=1e-6)
    np.testing.assert_allclose(mm, reference, atol=TOL)
    np.testing.assert_allclose(fit_bradley_terry_batch(wins), mm, atol=TOL)


def test_disconnected_graph_names_the_groups():
    wins = np.zeros((5, 5))
    wins[0, 1], wins[1, 0] = 3, 2
    wins[2, 3], wins[3, 4], wins[4, 2] = 1, 4, 2
    assert comparison_groups(wins) == [[0, 1], [2, 3, 4]]
    names = ["act", "diffusion", "pi0", "octo", "rt1"]
    with pytest.raises(DisconnectedComparisonsError) as err:
        fit_bradley_terry(wins, names=names)
    assert isinstance(err.value, ValueError)
    assert err.value.groups == [[0, 1], [2, 3, 4]]
    message = str(err.value)
    assert "[0, 1] (act, diffusion)" in message and "[2, 3, 4] (pi0, octo, rt1)" in message
    stack = np.stack([_near_ties()[:5, :5], wins])
    with pytest.raises(DisconnectedComparisonsError, match=r"batch index \(1,\)"):
        fit_bradley_terry_batch(stack)
    with pytest.raises(DisconnectedComparisonsError):
        bootstrap_bradley_terry(wins, n_boot=5)


def test_invalid_inputs_are_named():
    with pytest.raises(StatsError, match="non-zero diagonal"):
        fit_bradley_terry(np.array([[1, 2], [3, 0]]))
    with pytest.raises(StatsError, match="negative"):
        fit_bradley_terry(np.array([[0, -1], [3, 0]]))
    with pytest.raises(StatsError, match=r"shape \(\.\.\., P, P\)"):
        fit_bradley_terry(np.zeros((2, 3)))
    with pytest.raises(StatsError, match="integer"):
        bootstrap_bradley_terry(np.array([[0, 1.5], [2, 0]]), n_boot=5)
    with pytest.raises(ConfigError, match="n_boot"):  # a bad stats.n_boot is a config error
        bootstrap_bradley_terry(np.array([[0, 1], [2, 0]]), n_boot=0)


def test_batch_matches_plain_mm_per_matrix():
    rng = np.random.default_rng(11)
    P = 5
    stack = [simulate(rng.dirichlet(np.ones(P)), rng.integers(1, 40, size=(P, P)), rng) for _ in range(40)]
    stack[3][1, :] = 0  # a never-winning policy
    stack[7][:, 0] = 0  # a never-losing policy: the maximum is at the boundary
    stack[7][0, :] = np.maximum(stack[7][0, :], 1)
    np.fill_diagonal(stack[7], 0)
    stack = np.stack(stack)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # boundary cases end at the MM limit
        plain = np.array([fit_bradley_terry(m) for m in stack])
        batched = fit_bradley_terry_batch(stack)
        # 2400 matrices make two units of work, so two threads really share them.
        big = np.concatenate([stack] * 60)
        threaded = fit_bradley_terry_batch(big, n_threads=2)
        unthreaded = fit_bradley_terry_batch(big, n_threads=1)
        via_mm = fit_bradley_terry_batch(stack, method="mm")
    np.testing.assert_allclose(batched, plain, atol=TOL)
    np.testing.assert_array_equal(threaded, unthreaded)
    np.testing.assert_allclose(threaded[:40], batched, rtol=1e-12, atol=0)  # same up to rounding
    np.testing.assert_allclose(via_mm, plain, atol=1e-15)
    np.testing.assert_allclose(batched.sum(axis=1), 1.0, atol=1e-12)


def test_boundary_maximum_keeps_mm_semantics():
    # 1 never wins; once it is out, 0 never beat 2: no finite maximum exists and
    # MM's value after its last iteration is the answer.
    wins = np.array([[0, 5, 0], [0, 0, 0], [4, 3, 0]])
    with pytest.warns(RuntimeWarning, match="did not converge"):
        mm = fit_bradley_terry(wins)
    with pytest.warns(RuntimeWarning, match="did not converge"):
        batched = fit_bradley_terry_batch(wins)
    np.testing.assert_array_equal(batched, mm)
    assert mm[1] == 0.0 and mm[2] > 0.99


def test_init_does_not_change_the_answer():
    rng = np.random.default_rng(5)
    wins = simulate([0.5, 0.2, 0.2, 0.1], full_counts(4, 50), rng)
    cold = fit_bradley_terry_batch(wins)
    warm = fit_bradley_terry_batch(wins, init=[0.01, 0.01, 0.01, 0.97])
    np.testing.assert_allclose(warm, cold, atol=1e-10)


def test_recovers_known_strengths():
    truth = np.array([0.35, 0.25, 0.2, 0.12, 0.08])
    rng = np.random.default_rng(2024)
    wins = simulate(truth, full_counts(5, 20_000), rng)
    np.testing.assert_allclose(fit_bradley_terry(wins), truth, atol=0.005)


def test_bootstrap_replicates_match_plain_mm():
    rng = np.random.default_rng(8)
    truth = np.array([0.3, 0.25, 0.2, 0.15, 0.1])
    stack = np.stack([simulate(truth, full_counts(5, n), rng) for n in (60, 400)])
    stack[1, 4, :] = 0  # never-winning policy in the second matrix
    boot = bootstrap_bradley_terry(stack, n_boot=150, seed=4)
    assert boot.shape == (2, 150, 5)
    replicates = bootstrap_wins(stack, n_boot=150, seed=4)
    plain = np.array([[fit_bradley_terry(m) for m in reps] for reps in replicates])
    np.testing.assert_allclose(boot, plain, atol=TOL)
    assert np.all(boot[1, :, 4] == 0.0)


def test_bootstrap_small_counts_fall_back_to_mm():
    # Three comparisons per pair: many replicates have a policy that wins or loses
    # everything, including boundary cases that only MM defines.
    rng = np.random.default_rng(9)
    wins = simulate([0.4, 0.3, 0.2, 0.1], full_counts(4, 3), rng)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        boot = bootstrap_bradley_terry(wins, n_boot=40, seed=1)
        plain = np.array([fit_bradley_terry(m) for m in bootstrap_wins(wins, n_boot=40, seed=1)])
    np.testing.assert_allclose(boot, plain, atol=TOL)


def test_bootstrap_resampling_is_binomial_per_pair():
    wins = np.array([[0, 30, 0], [10, 0, 7], [0, 0, 0]])  # 2 never wins; 0-2 never compared
    reps = bootstrap_wins(wins, n_boot=4000, seed=0)
    n = wins + wins.T
    np.testing.assert_array_equal(reps + reps.transpose(0, 2, 1), np.broadcast_to(n, reps.shape))
    assert np.all(reps[:, 2, :] == 0)
    # wins[0, 1]* ~ Binomial(40, 0.75): mean 30, variance 7.5.
    assert abs(reps[:, 0, 1].mean() - 30) < 4 * np.sqrt(7.5 / 4000)
    assert abs(reps[:, 0, 1].var() - 7.5) < 0.6


def test_bootstrap_is_deterministic_and_thread_invariant():
    rng = np.random.default_rng(1)
    stack = np.stack([simulate([0.4, 0.35, 0.25], full_counts(3, 80), rng) for _ in range(3)])
    # 1200 replicates per matrix: one unit of work per matrix, shared by two threads.
    a = bootstrap_bradley_terry(stack, n_boot=1200, seed=12)
    b = bootstrap_bradley_terry(stack, n_boot=1200, seed=12, n_threads=2)
    c = bootstrap_bradley_terry(stack, n_boot=1200, seed=13)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # The first matrix of a stack draws the same replicates as on its own.
    np.testing.assert_array_equal(bootstrap_bradley_terry(stack[0], n_boot=1200, seed=12), a[0])
    # Seeds may be sequences of ints or a SeedSequence, which is not consumed.
    pair_seed = bootstrap_bradley_terry(stack[0], n_boot=50, seed=[12, 500])
    np.testing.assert_array_equal(pair_seed, bootstrap_bradley_terry(stack[0], n_boot=50, seed=[12, 500]))
    sequence = np.random.SeedSequence(12)
    first = bootstrap_bradley_terry(stack[0], n_boot=50, seed=sequence)
    np.testing.assert_array_equal(first, bootstrap_bradley_terry(stack[0], n_boot=50, seed=sequence))
    np.testing.assert_array_equal(first, bootstrap_bradley_terry(stack[0], n_boot=50, seed=12))


def test_bootstrap_intervals_cover_known_strengths():
    truth = np.array([0.3, 0.25, 0.2, 0.15, 0.1])
    wins = simulate(truth, full_counts(5, 2000), np.random.default_rng(21))
    lower, upper = bt_confidence_intervals(bootstrap_bradley_terry(wins, n_boot=1000, seed=0), level=0.95)
    assert np.all(lower <= 100 * truth) and np.all(100 * truth <= upper)
    assert np.all(upper - lower < 3.0)  # score points


def test_percentile_intervals_by_hand():
    grid = np.linspace(0.0, 1.0, 101)
    boot = np.stack([grid, 1.0 - grid], axis=1)  # (n_boot=101, P=2)
    lower, upper = bt_confidence_intervals(boot, level=0.95)
    np.testing.assert_allclose(lower, [2.5, 2.5])
    np.testing.assert_allclose(upper, [97.5, 97.5])
    assert bt_ci_width(boot, level=0.95) == pytest.approx(95.0)
    np.testing.assert_allclose(bt_ci_width(np.stack([boot, boot / 2]), level=0.95), [95.0, 47.5])
    lower90, upper90 = bt_confidence_intervals(boot, level=0.9)
    np.testing.assert_allclose([lower90[0], upper90[0]], [5.0, 95.0])
    with pytest.raises(ValueError, match="level"):
        bt_confidence_intervals(boot, level=95)
