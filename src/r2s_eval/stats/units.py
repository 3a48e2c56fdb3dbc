"""Unit bootstrap: resample the distinct rollout pairs behind the comparisons, within each task.

Comparisons of one policy pair that share a task and an initial configuration show the same
two rollouts, so a judge that sees such a pair again adds little new evidence.  The
binomial bootstrap (:func:`~r2s_eval.stats.bootstrap_bradley_terry`) treats every
comparison as independent; this one resamples *units* instead.

* A **unit** is one (policy pair, stratum, unit label) -- in the pipeline (pair, task,
  init_id): the rollout pair that all comparisons of that policy pair at that task and
  init share.  It carries its win counts in each orientation.
* A **stratum** is one (policy pair, task).  A replicate draws, in every stratum, as many
  units as the stratum has, uniformly with replacement from its units, and adds up their
  win counts; the per-task unit counts are kept, so the task balance of the design is too.
* Checkpoints are nested prefixes of each pair's comparison sequence.  At checkpoint ``c``
  a stratum holds the ``m[c, s]`` units seen in the first ``checkpoints[c]`` comparisons;
  units are ordered by first appearance, so those are its first ``m[c, s]`` units.
  Replicates are coupled across checkpoints: slot ``j`` of stratum ``s`` in replicate ``b``
  has one uniform variate ``V[b, start[s] + j]`` and picks unit ``start[s] +
  floor(V * m[c, s])`` at every checkpoint where ``j < m[c, s]`` (slots beyond ``m[c, s]``
  pick nothing).  Each checkpoint's replicate is exactly a stratified resample of that
  checkpoint's units, and replicate ``b`` at different checkpoints reuses the same draws,
  so a per-replicate average over checkpoints is meaningful.

Every compared pair keeps at least one unit with at least one comparison, so a replicate's
comparison graph has the same edges as the data; replicates are refitted with the same
batched Newton/MM solver as the binomial bootstrap.

Random stream: replicates come in blocks of :data:`BLOCK` (the last may be shorter); block
``q`` draws ``V = default_rng(seq).random((rows, n_units))`` with ``seq`` the
``SeedSequence`` with ``seed``'s entropy and spawn key ``seed.spawn_key + (UNIT_KEY, q)``.
Results depend neither on the thread count nor on how the work is split.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from r2s_eval.errors import ConfigError, StatsError
from r2s_eval.stats import _newton
from r2s_eval.stats._pairs import from_pairs, pair_index
from r2s_eval.stats.bradley_terry import (
    _check_n_boot,
    _check_names,
    _fit_pairs,
    _run_units,
    _warn_not_converged,
    fit_bradley_terry_batch,
)

BLOCK = 64  # replicates per block of draws (fixed, so the draws do not depend on threads)
UNIT_KEY = 0x756E6974  # spawn-key tag of the unit bootstrap's streams ("unit")


def tagged_seed(seed, *key: int) -> np.random.SeedSequence:
    """``SeedSequence(seed)``'s child with spawn key ``spawn_key + key``, built without
    spawning (a SeedSequence passed in is not advanced)."""
    if isinstance(seed, np.random.Generator):
        raise TypeError("seed must be an int, a sequence of ints or a SeedSequence, not a Generator")
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return np.random.SeedSequence(root.entropy, spawn_key=root.spawn_key + tuple(key), pool_size=root.pool_size)


@dataclass(frozen=True)
class ComparisonUnits:
    """Win counts of every unit at nested checkpoints (build with :func:`comparison_units`).

    Units are sorted by pair, stratum and first appearance; ``pair[u]`` indexes the
    unordered pairs ``(I[k], J[k])`` of ``np.triu_indices(n_policies, 1)``, and
    ``wins_ij[c, u]`` counts the unit's comparisons within checkpoint ``c`` that policy
    ``I[pair[u]]`` won (``wins_ji``: that ``J[pair[u]]`` won).
    """

    n_policies: int
    checkpoints: np.ndarray  # (C,) comparisons per pair at each checkpoint
    pair: np.ndarray  # (U,) pair index of each unit, non-decreasing
    stratum: np.ndarray  # (U,) stratum id 0..S-1, non-decreasing; one pair per stratum
    rank: np.ndarray  # (U,) position of the unit in its stratum, by first appearance
    wins_ij: np.ndarray  # (C, U)
    wins_ji: np.ndarray  # (C, U)

    @property
    def n_units(self) -> int:
        return int(self.pair.size)

    @property
    def stratum_start(self) -> np.ndarray:
        """(S,) index of each stratum's first unit."""
        return np.flatnonzero(self.rank == 0)

    @property
    def stratum_size(self) -> np.ndarray:
        """(C, S) units of each stratum seen by each checkpoint (a prefix of the stratum)."""
        seen = (self.wins_ij + self.wins_ji) > 0
        return np.add.reduceat(seen.astype(np.int64), self.stratum_start, axis=1) if self.n_units else seen[:, :0]

    def wins(self) -> np.ndarray:
        """(C, P, P) total win counts at each checkpoint."""
        P, K = self.n_policies, len(pair_index(self.n_policies)[0])
        C = len(self.checkpoints)
        w_ij = np.zeros((K, C))
        w_ji = np.zeros((K, C))
        np.add.at(w_ij, self.pair, self.wins_ij.T)
        np.add.at(w_ji, self.pair, self.wins_ji.T)
        return from_pairs(w_ij, w_ji, P)

    def units_per_pair(self) -> np.ndarray:
        """(C, K) distinct units of each pair seen by each checkpoint."""
        K = len(pair_index(self.n_policies)[0])
        out = np.zeros((len(self.checkpoints), K), dtype=np.int64)
        seen = ((self.wins_ij + self.wins_ji) > 0).astype(np.int64)
        for c in range(len(self.checkpoints)):
            out[c] = np.bincount(self.pair, weights=seen[c], minlength=K).astype(np.int64)
        return out


def comparison_units(
    policy_i,
    policy_j,
    i_won,
    unit,
    *,
    n_policies: int,
    stratum=None,
    position=None,
    checkpoints: Sequence[int] | None = None,
) -> ComparisonUnits:
    """Group comparisons into units: one row per comparison in, per-unit win counts out.

    ``policy_i``, ``policy_j``: the two policies' indices (either order); ``i_won``: whether
    ``policy_i`` was preferred; ``unit``: the unit label within the pair and stratum (the
    init_id); ``stratum``: the stratum label (the task; ``None``: one stratum per pair);
    ``position``: the comparison's place in its pair's sequence (``None``: row order within
    the pair); checkpoint ``c`` holds the comparisons with ``position < checkpoints[c]``
    (``None``: one checkpoint holding them all).  Labels may be any hashable values.
    """
    i = np.asarray(policy_i, dtype=np.int64)
    j = np.asarray(policy_j, dtype=np.int64)
    won = np.asarray(i_won, dtype=bool)
    N = i.size
    if not (i.shape == j.shape == won.shape == (N,)) or len(unit) != N:
        raise ValueError("policy_i, policy_j, i_won and unit must be 1-D of equal length")
    P = int(n_policies)
    if N and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= P):
        raise StatsError(f"policy indices must lie in 0..{P - 1}")
    if np.any(i == j):
        raise StatsError("a comparison needs two different policies")
    a, b = np.minimum(i, j), np.maximum(i, j)
    a_won = np.where(i < j, won, ~won)
    pair = a * (2 * P - a - 1) // 2 + (b - a - 1)  # row of (a, b) in np.triu_indices(P, 1)

    if position is None:  # row order within each pair
        pos = pd.Series(pair).groupby(pair).cumcount().to_numpy(dtype=np.int64)
    else:
        pos = np.asarray(position, dtype=np.int64)
        if pos.shape != (N,):
            raise ValueError("position must have one entry per comparison")
    if checkpoints is None:
        ck = np.array([int(pos.max()) + 1 if N else 0])
    else:
        ck = np.asarray([int(c) for c in checkpoints], dtype=np.int64)
        if ck.ndim != 1 or ck.size == 0 or np.any(ck <= 0):
            raise ConfigError(f"checkpoints must be positive comparison counts, got {list(checkpoints)}")

    strata = np.zeros(N, dtype=np.int64) if stratum is None else pd.factorize(pd.Series(list(stratum)))[0]
    if len(strata) != N:
        raise ValueError("stratum must have one entry per comparison")
    labels = pd.factorize(pd.Series(list(unit)))[0]
    keys = pd.DataFrame({"pair": pair, "stratum": strata, "unit": labels, "pos": pos})
    first = keys.groupby(["pair", "stratum", "unit"], sort=False)["pos"].transform("min")
    keys["first"] = first
    # One id per unit, numbered in (pair, stratum, first appearance) order.
    table = keys.drop_duplicates(["pair", "stratum", "unit"]).sort_values(["pair", "stratum", "first", "unit"])
    table = table.reset_index(drop=True)
    uid = pd.MultiIndex.from_frame(table[["pair", "stratum", "unit"]]).get_indexer(
        pd.MultiIndex.from_frame(keys[["pair", "stratum", "unit"]])
    )
    new_stratum = np.ones(len(table), dtype=bool)
    new_stratum[1:] = (np.diff(table["pair"]) != 0) | (np.diff(table["stratum"]) != 0)
    stratum_id = np.cumsum(new_stratum) - 1
    rank = np.arange(len(table)) - np.flatnonzero(new_stratum)[stratum_id]
    U = len(table)
    wins_ij = np.zeros((len(ck), U))
    wins_ji = np.zeros((len(ck), U))
    for c, n in enumerate(ck):
        inside = pos < n
        wins_ij[c] = np.bincount(uid, weights=inside & a_won, minlength=U)
        wins_ji[c] = np.bincount(uid, weights=inside & ~a_won, minlength=U)
    return ComparisonUnits(
        n_policies=P,
        checkpoints=ck,
        pair=table["pair"].to_numpy(dtype=np.int64),
        stratum=stratum_id.astype(np.int64),
        rank=rank.astype(np.int64),
        wins_ij=wins_ij,
        wins_ji=wins_ji,
    )


def _block_rows(n_boot: int) -> list[slice]:
    return [slice(s, min(s + BLOCK, n_boot)) for s in range(0, n_boot, BLOCK)]


def _draw_block(units: ComparisonUnits, rows: int, seq: np.random.SeedSequence) -> tuple[np.ndarray, np.ndarray]:
    """Resampled pair-form wins of one block: two (C, rows, K) arrays."""
    P, C, U = units.n_policies, len(units.checkpoints), units.n_units
    K = len(pair_index(P)[0])
    V = np.random.default_rng(seq).random((rows, U))
    out_ij = np.zeros((C, rows, K))
    out_ji = np.zeros((C, rows, K))
    start = units.stratum_start[units.stratum]  # (U,) first unit of each slot's stratum
    sizes = units.stratum_size
    previous = None
    for c in range(C):
        size = sizes[c, units.stratum]  # (U,)
        if previous is None or not np.array_equal(size, previous):
            # New units seen since the last checkpoint: redo the picks (same variates).
            previous = size
            cols = np.flatnonzero(units.rank < size)  # slots that draw at this checkpoint
            local = V if cols.size == U else V[:, cols]
            local = np.minimum((local * size[cols]).astype(np.int64), size[cols] - 1)
            idx = start[cols] + local  # (rows, A) units drawn
            pairs = units.pair[cols]
            seg = np.r_[0, np.flatnonzero(np.diff(pairs)) + 1]
        if cols.size == 0:
            continue
        out_ij[c][:, pairs[seg]] = np.add.reduceat(units.wins_ij[c][idx], seg, axis=1)
        out_ji[c][:, pairs[seg]] = np.add.reduceat(units.wins_ji[c][idx], seg, axis=1)
    return out_ij, out_ji


def unit_bootstrap_wins(units: ComparisonUnits, n_boot: int, seed=0) -> np.ndarray:
    """The resampled win matrices behind :func:`unit_bootstrap_bradley_terry`: ``(C, n_boot, P, P)``."""
    n_boot = _check_n_boot(n_boot)
    P, C = units.n_policies, len(units.checkpoints)
    out = np.empty((C, n_boot, P, P))
    for q, rows in enumerate(_block_rows(n_boot)):
        w_ij, w_ji = _draw_block(units, rows.stop - rows.start, tagged_seed(seed, UNIT_KEY, q))
        m = w_ij.shape[1]
        mats = from_pairs(w_ij.reshape(C * m, -1).T, w_ji.reshape(C * m, -1).T, P)
        out[:, rows] = mats.reshape(C, m, P, P)
    return out


def unit_bootstrap_bradley_terry(
    units: ComparisonUnits,
    n_boot: int,
    seed=0,
    *,
    names: Sequence[str] | None = None,
    n_threads: int | None = 1,
) -> np.ndarray:
    """Unit-bootstrap Bradley-Terry strengths at every checkpoint: ``(C, n_boot, P)``.

    Each replicate is a stratified resample of the units (see the module docstring and
    :func:`unit_bootstrap_wins`), refitted; every replicate agrees with
    :func:`~r2s_eval.stats.fit_bradley_terry` on its resampled matrix.  Deterministic for a
    given ``seed`` (an int, a sequence of ints or a ``SeedSequence``); ``n_threads``
    (``None``: all usable CPUs) does not change the result.
    """
    n_boot = _check_n_boot(n_boot)
    P, C = units.n_policies, len(units.checkpoints)
    _check_names(names, P)
    point = fit_bradley_terry_batch(units.wins(), names=names)  # also checks connectivity
    if P == 1:
        return np.ones((C, n_boot, 1))
    theta0 = np.log(np.maximum(point, 1e-300))  # (C, P)
    strengths = np.empty((C, n_boot, P))
    blocks = _block_rows(n_boot)

    def task(q: int, work: _newton.Workspace) -> int:
        rows = blocks[q]
        m = rows.stop - rows.start
        w_ij, w_ji = _draw_block(units, m, tagged_seed(seed, UNIT_KEY, q))  # (C, m, K)
        b_ij = np.ascontiguousarray(w_ij.reshape(C * m, -1).T)
        b_ji = np.ascontiguousarray(w_ji.reshape(C * m, -1).T)
        init = np.repeat(theta0.T, m, axis=1)  # replicates start from their checkpoint's estimate
        fitted, count = _fit_pairs(b_ij, b_ji, P, init, work=work)
        strengths[:, rows] = fitted.T.reshape(C, m, P)
        return count

    not_converged = _run_units(task, len(blocks), P, n_threads)
    _warn_not_converged(not_converged, C * n_boot)
    return strengths
