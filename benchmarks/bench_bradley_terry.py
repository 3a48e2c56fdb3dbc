"""Paper-scale Bradley-Terry bootstrap: wall time of the batched path vs a choix loop.

Scale: 6 policies (15 pairs), 16 nested checkpoints of 500..2000 comparisons per
policy pair (step 100), 8 judges and 1000 bootstrap replicates, i.e. 128,000 fits.
Win counts come from a seeded simulation with known strengths.  The timed
computation is one ``bootstrap_bradley_terry`` call on the (16, 8, 6, 6) stack:
validation, point estimates, binomial resampling and all replicate fits.

The baseline fits replicates one at a time with choix's fastest call on the same
counts, ``choix.ilsr_pairwise_dense`` on the (P, P) win matrix; it is timed on a
small subset spread over all checkpoints and judges and extrapolated linearly to
128,000 fits.  For reference, ``choix.ilsr_pairwise`` on the expanded list of
(winner, loser) tuples, one per comparison (expansion not timed), is timed on the
same subset; it is far slower, as its cost grows with the number of comparisons.
Plain batched MM on the same replicates is timed too, as a yardstick measured
under the same machine load, and the unit bootstrap (the distinct task/init
rollout pairs resampled within each task) on a simulated design of 7 tasks x 30
inits per pair.

Run: ``python benchmarks/bench_bradley_terry.py [--repeats 3] [--choix-fits 200] [--n-boot 1000]``
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from r2s_eval.stats import (
    bootstrap_bradley_terry,
    bootstrap_wins,
    bt_ci_width,
    comparison_units,
    fit_bradley_terry,
    fit_bradley_terry_batch,
    unit_bootstrap_bradley_terry,
)

N_POLICIES = 6
CHECKPOINTS = np.arange(500, 2001, 100)  # comparisons per policy pair
N_JUDGES = 8
# The configured bootstrap (conf/stats/default.yaml), read rather than copied.
_STATS = OmegaConf.load(Path(__file__).resolve().parents[1] / "conf" / "stats" / "default.yaml")
N_BOOT = int(_STATS.n_boot)
LEVEL = float(_STATS.ci_level)
TRUE_SCORES = np.array([30.0, 24.0, 17.0, 13.0, 9.0, 7.0])  # 100 b, sums to 100


def simulate_wins(seed: int = 0) -> np.ndarray:
    """Nested win counts (checkpoint, judge, P, P) from known strengths.

    Judges differ in how sharply they separate policies (a temperature on theta)
    and each comparison is an independent draw; a checkpoint holds the first
    ``CHECKPOINTS[c]`` comparisons of every pair, so checkpoints are nested.
    """
    rng = np.random.default_rng(seed)
    theta = np.log(TRUE_SCORES / TRUE_SCORES.sum())
    sharpness = np.linspace(0.6, 1.2, N_JUDGES)
    I, J = np.triu_indices(N_POLICIES, 1)
    p = 1.0 / (1.0 + np.exp(-sharpness[:, None] * (theta[I] - theta[J])[None, :]))  # (judge, pair)
    outcomes = rng.random((N_JUDGES, len(I), CHECKPOINTS[-1])) < p[:, :, None]
    cumulative = np.cumsum(outcomes, axis=-1)[:, :, CHECKPOINTS - 1]  # (judge, pair, ckpt)
    wins = np.zeros((len(CHECKPOINTS), N_JUDGES, N_POLICIES, N_POLICIES))
    first = cumulative.transpose(2, 0, 1)
    wins[:, :, I, J] = first
    wins[:, :, J, I] = CHECKPOINTS[:, None, None] - first
    return wins


def expand(matrix: np.ndarray) -> list[tuple[int, int]]:
    """The (winner, loser) list that choix takes."""
    i, j = np.nonzero(matrix)
    return [(a, b) for a, b, c in zip(i, j, matrix[i, j].astype(int)) for _ in range(c)]


def _normalise(params: np.ndarray) -> np.ndarray:
    strengths = np.exp(params - params.max())
    return strengths / strengths.sum()


def choix_dense_fit(matrix: np.ndarray) -> np.ndarray:
    """choix's fastest call on these counts: ILSR on the dense win matrix."""
    import choix

    return _normalise(choix.ilsr_pairwise_dense(matrix))


def choix_list_fit(n_policies: int, data: list[tuple[int, int]]) -> np.ndarray:
    """ILSR on one (winner, loser) tuple per comparison."""
    import choix

    return _normalise(choix.ilsr_pairwise(n_policies, data))


def simulate_units(seed: int = 0, tasks: int = 7, inits: int = 30, spread: float = 1.5):
    """One judge's comparisons at CHECKPOINTS, as units: every comparison of a pair at the same
    task and init shows the same two rollouts, whose latent preference is drawn once."""
    rng = np.random.default_rng(seed)
    theta = np.log(TRUE_SCORES / TRUE_SCORES.sum())
    I, J = np.triu_indices(N_POLICIES, 1)
    n = CHECKPOINTS[-1]
    task = np.tile(np.arange(n) % tasks, len(I))
    init = rng.integers(inits, size=len(I) * n)
    pair = np.repeat(np.arange(len(I)), n)
    latent = theta[I][:, None, None] - theta[J][:, None, None] + rng.normal(0, spread, size=(len(I), tasks, inits))
    p = 1.0 / (1.0 + np.exp(-latent[pair, task, init]))
    return comparison_units(
        I[pair], J[pair], rng.random(p.size) < p, init, n_policies=N_POLICIES, stratum=task,
        position=np.tile(np.arange(n), len(I)), checkpoints=CHECKPOINTS,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="timed runs of the batched path")
    parser.add_argument("--choix-fits", type=int, default=200, help="baseline fits to time (each choix call)")
    parser.add_argument("--check-fits", type=int, default=300, help="replicates checked against MM")
    parser.add_argument("--n-boot", type=int, default=N_BOOT, help="bootstrap replicates (smaller: a quick check)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    wins = simulate_wins(args.seed)
    n_fits = wins.shape[0] * wins.shape[1] * args.n_boot
    print(
        f"scale: {N_POLICIES} policies, {len(CHECKPOINTS)} checkpoints "
        f"({CHECKPOINTS[0]}..{CHECKPOINTS[-1]} per pair), {N_JUDGES} judges, "
        f"{args.n_boot} replicates = {n_fits:,} fits; load average {os.getloadavg()[0]:.2f} "
        f"on {os.cpu_count()} CPUs"
    )

    bootstrap_bradley_terry(wins[:1, :1], n_boot=10, seed=1)  # warm imports and caches
    best = {}
    for threads, label in ((None, "all cores"), (1, "1 thread")):
        walls, cpus = [], []
        for _ in range(args.repeats):
            wall, cpu = time.perf_counter(), time.process_time()
            boot = bootstrap_bradley_terry(wins, n_boot=args.n_boot, seed=args.seed, n_threads=threads)
            walls.append(time.perf_counter() - wall)
            cpus.append(time.process_time() - cpu)
        best[label] = min(walls)
        print(
            f"batched bootstrap, {label} (resampling + {n_fits:,} fits): wall "
            + ", ".join(f"{t:.3f}" for t in walls)
            + " s; cpu "
            + ", ".join(f"{t:.3f}" for t in cpus)
            + " s"
        )

    # Same-conditions yardstick: plain batched MM on the very same replicates.
    reps = bootstrap_wins(wins, n_boot=args.n_boot, seed=args.seed).reshape(-1, N_POLICIES, N_POLICIES)
    wall = time.perf_counter()
    fit_bradley_terry_batch(reps, method="mm", n_threads=1)
    print(f"plain batched MM on the same replicates (fits only, 1 thread): {time.perf_counter() - wall:.3f} s")

    # Agreement: refit a random sample of replicates with plain MM.
    rng = np.random.default_rng(args.seed + 1)
    flat_boot = boot.reshape(-1, N_POLICIES)
    sample = rng.choice(len(reps), size=min(args.check_fits, len(reps)), replace=False)
    diff = max(np.abs(fit_bradley_terry(reps[k]) - flat_boot[k]).max() for k in sample)
    status = "OK" if diff <= 1e-6 else "FAILED"
    print(f"agreement with plain MM on {args.check_fits} replicates: max |diff| = {diff:.2e} ({status})")

    # Baselines on replicates spread over every checkpoint and judge.
    subset = bootstrap_wins(wins, n_boot=2, seed=args.seed + 2).reshape(-1, N_POLICIES, N_POLICIES)
    subset = subset[rng.choice(len(subset), size=min(args.choix_fits, len(subset)), replace=False)]
    start = time.perf_counter()
    dense = [choix_dense_fit(m) for m in subset]
    per_fit = (time.perf_counter() - start) / len(subset)
    dense_diff = max(np.abs(b - fit_bradley_terry(m)).max() for b, m in zip(dense, subset))
    extrapolated = per_fit * n_fits
    print(
        f"choix.ilsr_pairwise_dense loop (win matrix): {per_fit * 1e3:.3f} ms/fit on {len(subset)} fits "
        f"-> {extrapolated:.1f} s for {n_fits:,} fits (max |diff| vs MM {dense_diff:.1e})"
    )
    datasets = [expand(m) for m in subset]  # not timed: only the choix calls count
    start = time.perf_counter()
    listed = [choix_list_fit(N_POLICIES, data) for data in datasets]
    per_fit_list = (time.perf_counter() - start) / len(subset)
    list_diff = max(np.abs(b - fit_bradley_terry(m)).max() for b, m in zip(listed, subset))
    print(
        f"choix.ilsr_pairwise loop (one tuple per comparison, for reference): {per_fit_list * 1e3:.2f} ms/fit "
        f"-> {per_fit_list * n_fits:.0f} s for {n_fits:,} fits (max |diff| vs MM {list_diff:.1e})"
    )
    for label, wall in best.items():
        print(
            f"speed-up vs choix.ilsr_pairwise_dense loop, {label}: {extrapolated / wall:,.1f}x "
            f"(best run {wall:.3f} s); vs the tuple-list loop: {per_fit_list * n_fits / wall:,.0f}x"
        )

    # The unit bootstrap of one judge (all checkpoints), on a design where comparisons repeat
    # rollout pairs; its binomial counterpart on the same win counts for the interval widths.
    units = simulate_units(args.seed)
    walls = []
    for _ in range(args.repeats):
        wall = time.perf_counter()
        unit_boot = unit_bootstrap_bradley_terry(units, n_boot=args.n_boot, seed=args.seed)
        walls.append(time.perf_counter() - wall)
    binom_boot = bootstrap_bradley_terry(units.wins(), n_boot=args.n_boot, seed=args.seed)
    ratio = bt_ci_width(unit_boot, LEVEL)[-1] / bt_ci_width(binom_boot, LEVEL)[-1]
    print(
        f"unit bootstrap, one judge ({units.n_units:,} units, {len(CHECKPOINTS)} checkpoints, "
        f"{len(CHECKPOINTS) * args.n_boot:,} fits, 1 thread): wall " + ", ".join(f"{t:.3f}" for t in walls)
        + f" s; CI width unit / binomial at {CHECKPOINTS[-1]}: {ratio:.2f}"
    )
    if diff > 1e-6:
        raise SystemExit("batched results disagree with MM")


if __name__ == "__main__":
    main()
