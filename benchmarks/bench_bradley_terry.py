"""Paper-scale Bradley-Terry bootstrap: wall time of the batched path vs a choix loop.

Scale: 6 policies (15 pairs), 16 nested checkpoints of 500..2000 comparisons per
policy pair (step 100), 8 judges and 1000 bootstrap replicates, i.e. 128,000 fits.
Win counts come from a seeded simulation with known strengths.  The timed
computation is one ``bootstrap_bradley_terry`` call on the (16, 8, 6, 6) stack:
validation, point estimates, binomial resampling and all replicate fits.

The baseline fits replicates one at a time with ``choix.ilsr_pairwise`` on the
expanded (winner, loser) list (expansion not timed); it is timed on a small subset
spread over all checkpoints and judges and extrapolated linearly to 128,000 fits.
Plain batched MM on the same replicates is timed too, as a yardstick measured
under the same machine load.

Run: ``python benchmarks/bench_bradley_terry.py [--repeats 3] [--choix-fits 200]``
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from r2s_eval.stats import (
    bootstrap_bradley_terry,
    bootstrap_wins,
    fit_bradley_terry,
    fit_bradley_terry_batch,
)

N_POLICIES = 6
CHECKPOINTS = np.arange(500, 2001, 100)  # comparisons per policy pair
N_JUDGES = 8
N_BOOT = 1000
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


def choix_fit(n_policies: int, data: list[tuple[int, int]]) -> np.ndarray:
    import choix

    params = choix.ilsr_pairwise(n_policies, data)
    strengths = np.exp(params - params.max())
    return strengths / strengths.sum()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="timed runs of the batched path")
    parser.add_argument("--choix-fits", type=int, default=200, help="baseline fits to time")
    parser.add_argument("--check-fits", type=int, default=300, help="replicates checked against MM")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    wins = simulate_wins(args.seed)
    n_fits = wins.shape[0] * wins.shape[1] * N_BOOT
    print(
        f"scale: {N_POLICIES} policies, {len(CHECKPOINTS)} checkpoints "
        f"({CHECKPOINTS[0]}..{CHECKPOINTS[-1]} per pair), {N_JUDGES} judges, "
        f"{N_BOOT} replicates = {n_fits:,} fits; load average {os.getloadavg()[0]:.2f} "
        f"on {os.cpu_count()} CPUs"
    )

    bootstrap_bradley_terry(wins[:1, :1], n_boot=10, seed=1)  # warm imports and caches
    best = {}
    for threads, label in ((None, "all cores"), (1, "1 thread")):
        walls, cpus = [], []
        for _ in range(args.repeats):
            wall, cpu = time.perf_counter(), time.process_time()
            boot = bootstrap_bradley_terry(wins, n_boot=N_BOOT, seed=args.seed, n_threads=threads)
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
    reps = bootstrap_wins(wins, n_boot=N_BOOT, seed=args.seed).reshape(-1, N_POLICIES, N_POLICIES)
    wall = time.perf_counter()
    fit_bradley_terry_batch(reps, method="mm", n_threads=1)
    print(f"plain batched MM on the same replicates (fits only, 1 thread): {time.perf_counter() - wall:.3f} s")

    # Agreement: refit a random sample of replicates with plain MM.
    rng = np.random.default_rng(args.seed + 1)
    flat_boot = boot.reshape(-1, N_POLICIES)
    sample = rng.choice(len(reps), size=args.check_fits, replace=False)
    diff = max(np.abs(fit_bradley_terry(reps[k]) - flat_boot[k]).max() for k in sample)
    status = "OK" if diff <= 1e-6 else "FAILED"
    print(f"agreement with plain MM on {args.check_fits} replicates: max |diff| = {diff:.2e} ({status})")

    # Baseline on replicates spread over every checkpoint and judge.
    subset = bootstrap_wins(wins, n_boot=2, seed=args.seed + 2).reshape(-1, N_POLICIES, N_POLICIES)
    subset = subset[rng.choice(len(subset), size=min(args.choix_fits, len(subset)), replace=False)]
    datasets = [expand(m) for m in subset]  # not timed: only the choix calls count
    start = time.perf_counter()
    baseline = [choix_fit(N_POLICIES, data) for data in datasets]
    per_fit = (time.perf_counter() - start) / len(subset)
    choix_diff = max(np.abs(b - fit_bradley_terry(m)).max() for b, m in zip(baseline, subset))
    extrapolated = per_fit * n_fits
    print(
        f"choix.ilsr_pairwise loop: {per_fit * 1e3:.2f} ms/fit on {len(subset)} fits "
        f"-> {extrapolated:.0f} s for {n_fits:,} fits (max |diff| vs MM {choix_diff:.1e})"
    )
    for label, wall in best.items():
        print(f"speed-up vs choix loop, {label}: {extrapolated / wall:,.0f}x (best run {wall:.3f} s)")
    if diff > 1e-6:
        raise SystemExit("batched results disagree with MM")


if __name__ == "__main__":
    main()
