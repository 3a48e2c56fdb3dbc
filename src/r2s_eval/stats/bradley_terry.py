"""Bradley-Terry strengths from A/B preference counts, with a vectorised bootstrap.

Convention: ``wins[i, j]`` counts how often a rollout of policy ``i`` was preferred
over one of policy ``j`` (diagonal zero).  Strengths ``b`` are non-negative and sum
to 1, ``theta = log b`` is the natural parametrisation, and the reported score is
``s = 100 b`` (:func:`bt_scores`).

Hunter's MM algorithm defines the answer (:func:`fit_bradley_terry`).  The batched
solver (:func:`fit_bradley_terry_batch`, used by :func:`bootstrap_bradley_terry`)
reaches the same maximum-likelihood point with Newton steps on ``theta`` and hands
any matrix whose maximum is not attained at finite ``theta`` to the same MM
iteration, so both paths agree.

Internally a batch of matrices is held in *pair form*: one row per unordered pair
``k = (I[k], J[k])`` with ``I < J`` and one column per matrix, so that every
vectorised operation runs over a long contiguous batch axis.
"""

from __future__ import annotations

import os
import queue
import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from r2s_eval.stats import _newton
from r2s_eval.stats._pairs import (
    from_pairs,
    pair_index,
    policy_totals,
    to_pairs,
    transitive_closure,
)

from r2s_eval.errors import ConfigError, StatsError

MM_MAX_ITER = 1000
MM_TOL = 1e-8  # max abs change of the normalised strengths between MM iterations
EPS = 1e-12  # keeps MM denominators positive when two strengths reach zero


class DisconnectedComparisonsError(StatsError):
    """The comparison graph splits into groups with no comparisons between them.

    Strengths of policies in different groups are not comparable, so no fit is
    returned.  ``groups`` lists the policy indices of each group; ``batch_index``
    locates the offending matrix in a batch (``None`` for a single matrix).
    """

    def __init__(
        self,
        groups: list[list[int]],
        names: Sequence[str] | None = None,
        batch_index: tuple[int, ...] | None = None,
    ):
        self.groups = groups
        self.batch_index = batch_index

        def label(group: list[int]) -> str:
            text = "[" + ", ".join(str(i) for i in group) + "]"
            if names is not None:
                text += " (" + ", ".join(str(names[i]) for i in group) + ")"
            return text

        where = "" if batch_index is None else f" of win matrix at batch index {batch_index}"
        super().__init__(
            f"comparison graph{where} is not connected: no comparisons between the policy groups "
            + " | ".join(label(g) for g in groups)
            + "; compare at least one pair across the groups or fit them separately"
        )


# --------------------------------------------------------------------------- input


def _as_wins(wins, *, integer: bool = False) -> np.ndarray:
    arr = np.asarray(wins, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-1] != arr.shape[-2]:
        raise StatsError(f"wins must have shape (..., P, P), got {arr.shape}")
    if arr.shape[-1] == 0:
        raise StatsError("wins has no policies")
    if not np.all(np.isfinite(arr)):
        raise StatsError("wins contains NaN or infinite counts")
    if np.any(arr < 0):
        raise StatsError("wins contains negative counts")
    diag = np.diagonal(arr, axis1=-2, axis2=-1)
    if np.any(diag != 0):
        raise StatsError("wins has a non-zero diagonal: a policy cannot be compared with itself")
    if integer and np.any(arr != np.round(arr)):
        raise StatsError("bootstrap resampling needs integer win counts")
    return arr


def _check_names(names: Sequence[str] | None, n_policies: int) -> None:
    if names is not None and len(names) != n_policies:
        raise StatsError(f"names has {len(names)} entries for {n_policies} policies")


def comparison_groups(wins) -> list[list[int]]:
    """Connected components of the comparison graph (policies linked when ``n_ij > 0``)."""
    arr = _as_wins(wins)
    if arr.ndim != 2:
        raise ValueError(f"comparison_groups takes one (P, P) matrix, got shape {arr.shape}")
    linked = (arr + arr.T) > 0
    unseen = set(range(len(arr)))
    groups = []
    while unseen:
        stack = [min(unseen)]
        group = set(stack)
        while stack:
            i = stack.pop()
            for j in np.flatnonzero(linked[i]):
                if int(j) not in group:
                    group.add(int(j))
                    stack.append(int(j))
        unseen -= group
        groups.append(sorted(group))
    return groups


def _check_connected(arr: np.ndarray, names: Sequence[str] | None) -> None:
    """Raise DisconnectedComparisonsError for the first disconnected matrix in a batch."""
    P = arr.shape[-1]
    flat = arr.reshape(-1, P, P)
    compared = (flat + flat.transpose(0, 2, 1)) > 0
    # Fast path: a complete comparison graph is connected.
    sparse = np.flatnonzero(~(compared | np.eye(P, dtype=bool)).all(axis=(1, 2)))
    if sparse.size == 0:
        return
    reach = transitive_closure(compared[sparse].transpose(1, 2, 0))
    bad = sparse[~reach.all(axis=(0, 1))]
    if bad.size:
        first = int(bad[0])
        index = np.unravel_index(first, arr.shape[:-2]) if arr.ndim > 2 else None
        groups = comparison_groups(flat[first])
        raise DisconnectedComparisonsError(
            groups, names, None if index is None else tuple(int(i) for i in index)
        )


# ------------------------------------------------------------------------------ MM


def _mm_pairs(
    w_ij: np.ndarray, w_ji: np.ndarray, P: int, max_iter: int = MM_MAX_ITER, tol: float = MM_TOL
) -> tuple[np.ndarray, np.ndarray]:
    """Hunter's MM for each pair-form column: strengths (P, B) and a converged flag (B,).

    Each column stops at its own convergence, exactly as a separate fit would.
    """
    I, J = pair_index(P)
    B = w_ij.shape[1]
    n = w_ij + w_ji
    W = policy_totals(w_ij, w_ji, P)
    strengths = np.empty((P, B))
    converged = np.zeros(B, dtype=bool)
    active = np.arange(B)
    b = np.full((P, B), 1.0 / P)
    for _ in range(max_iter):
        s = n / (b[I] + b[J] + EPS)
        new = W / policy_totals(s, s, P)
        new /= new.sum(axis=0)
        change = np.abs(new - b).max(axis=0)
        b = new
        done = change < tol
        if done.any():
            strengths[:, active[done]] = b[:, done]
            converged[active[done]] = True
            keep = ~done
            active, b, n, W = active[keep], b[:, keep], n[:, keep], W[:, keep]
            if active.size == 0:
                break
    strengths[:, active] = b
    return strengths, converged


# ------------------------------------------------------------------------- solvers


def _fit_pairs(
    w_ij: np.ndarray,
    w_ji: np.ndarray,
    P: int,
    theta0: np.ndarray | None = None,
    method: str = "newton",
    work: _newton.Workspace | None = None,
) -> tuple[np.ndarray, int]:
    """Strengths (P, B) for connected pair-form columns; also the count of MM fits
    that hit the iteration limit."""
    B = w_ij.shape[1]
    if method == "mm":
        strengths, converged = _mm_pairs(w_ij, w_ji, P)
        return strengths, int((~converged).sum())
    if method != "newton":
        raise ValueError(f"method must be 'newton' or 'mm', got {method!r}")
    strengths = np.empty((P, B))
    regular = _newton.regular_columns(w_ij, w_ji, P)
    solved = regular.copy()
    if regular.all():
        strengths, solved = _newton.newton(w_ij, w_ji, P, theta0, work)
    elif regular.any():
        idx = np.flatnonzero(regular)
        init = None if theta0 is None else theta0[:, idx]
        strengths[:, idx], solved[idx] = _newton.newton(w_ij[:, idx], w_ji[:, idx], P, init, work)
    rest = np.flatnonzero(~solved)
    not_converged = 0
    if rest.size:
        strengths[:, rest], converged = _mm_pairs(w_ij[:, rest], w_ji[:, rest], P)
        not_converged = int((~converged).sum())
    return strengths, not_converged


def _run_units(task, n_units: int, P: int, n_threads: int | None) -> int:
    """Run ``task(unit, workspace)`` for every unit, on up to ``n_threads`` threads.

    Units are fixed by the data, not by the thread count, and each writes its own
    slice of the output, so results do not depend on ``n_threads``.  NumPy
    releases the GIL inside its loops, so threads share out the arithmetic.
    Returns the sum of the tasks' return values.
    """
    if n_threads is None:
        n_threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if int(n_threads) != n_threads or n_threads < 1:
        raise ConfigError(f"n_threads must be a positive integer or None, got {n_threads!r}")
    n_threads = min(int(n_threads), n_units)
    if n_threads <= 1:
        work = _newton.Workspace(P)
        return sum(task(unit, work) for unit in range(n_units))
    pool: queue.SimpleQueue = queue.SimpleQueue()
    for _ in range(n_threads):
        pool.put(_newton.Workspace(P))

    def run(unit: int) -> int:
        work = pool.get()
        try:
            return task(unit, work)
        finally:
            pool.put(work)

    with ThreadPoolExecutor(max_workers=n_threads) as executor:
        return sum(executor.map(run, range(n_units)))


def _warn_not_converged(count: int, total: int) -> None:
    if count:
        warnings.warn(
            f"{count} of {total} Bradley-Terry fits did not converge within {MM_MAX_ITER} MM "
            "iterations: within some group of policies one side won every comparison, so the "
            "maximum likelihood lies at the boundary; the MM values after the last iteration "
            "are returned",
            RuntimeWarning,
            stacklevel=3,
        )


def fit_bradley_terry(wins, *, names: Sequence[str] | None = None) -> np.ndarray:
    """Bradley-Terry strengths of one (P, P) win matrix by Hunter's MM algorithm.

    Iterates ``b_i <- W_i / sum_{j != i} n_ij / (b_i + b_j)`` (``W_i`` total wins of
    ``i``, ``n_ij = wins[i, j] + wins[j, i]``), renormalising to sum 1, from uniform
    strengths, until the largest change is below 1e-8 or for at most 1000 iterations.

    A policy that never wins gets strength 0.  Raises
    :class:`DisconnectedComparisonsError` (a ``ValueError``) naming the groups when
    some policies were never compared, directly or indirectly, with the others;
    ``names`` labels policies in that message.
    """
    arr = _as_wins(wins)
    if arr.ndim != 2:
        raise StatsError(
            f"fit_bradley_terry takes one (P, P) matrix, got shape {arr.shape}; "
            "use fit_bradley_terry_batch for a stack"
        )
    P = arr.shape[0]
    _check_names(names, P)
    _check_connected(arr, names)
    if P == 1:
        return np.ones(1)
    w_ij, w_ji = to_pairs(arr[None])
    strengths, converged = _mm_pairs(w_ij, w_ji, P)
    _warn_not_converged(int((~converged).sum()), 1)
    return strengths[:, 0]


def fit_bradley_terry_batch(
    wins_batch,
    init=None,
    *,
    names: Sequence[str] | None = None,
    method: str = "newton",
    n_threads: int | None = 1,
) -> np.ndarray:
    """Fit every (P, P) matrix of a ``(..., P, P)`` stack; returns ``(..., P)`` strengths.

    Agrees with :func:`fit_bradley_terry` on each matrix (to well below 1e-6).  The
    default ``method="newton"`` runs batched Newton steps on ``theta = log b``, each
    matrix stopping at its own convergence, and hands every matrix whose maximum
    likelihood is not attained (some group won or lost all its comparisons, beyond
    policies that never win at all) to MM.  ``method="mm"`` runs MM on all of them.

    ``init``: optional starting strengths broadcastable to ``(..., P)`` (e.g. the
    point estimate when fitting bootstrap replicates).  It only speeds Newton up: the
    answer does not depend on it, and MM always starts from uniform strengths.
    ``n_threads``: threads to share the work (``None``: all usable CPUs); the
    result does not depend on it.  One by default, as pipeline jobs already run
    side by side.
    """
    arr = _as_wins(wins_batch)
    batch_shape, P = arr.shape[:-2], arr.shape[-1]
    _check_names(names, P)
    if method not in ("newton", "mm"):
        raise ValueError(f"method must be 'newton' or 'mm', got {method!r}")
    _check_connected(arr, names)
    flat = arr.reshape(-1, P, P)
    if P == 1:
        return np.ones(batch_shape + (1,))
    theta0 = None
    if init is not None:
        start = np.broadcast_to(np.asarray(init, dtype=np.float64), batch_shape + (P,))
        if np.any(~np.isfinite(start)) or np.any(start < 0):
            raise StatsError("init must hold finite, non-negative strengths")
        theta0 = np.log(np.maximum(start.reshape(-1, P).T, 1e-300))
    w_ij, w_ji = to_pairs(flat)
    B = w_ij.shape[1]
    strengths = np.empty((P, B))
    chunk = _newton.block_size(P)

    def task(unit: int, work: _newton.Workspace) -> int:
        cols = slice(unit * chunk, min((unit + 1) * chunk, B))
        init_cols = None if theta0 is None else theta0[:, cols]
        strengths[:, cols], count = _fit_pairs(w_ij[:, cols], w_ji[:, cols], P, init_cols, method, work)
        return count

    not_converged = _run_units(task, -(-B // chunk), P, n_threads)
    _warn_not_converged(not_converged, B)
    return strengths.T.reshape(batch_shape + (P,))


# ----------------------------------------------------------------------- bootstrap


def _check_n_boot(n_boot) -> int:
    if isinstance(n_boot, bool) or int(n_boot) != n_boot or n_boot < 1:
        raise ConfigError(f"n_boot must be a positive integer, got {n_boot!r}")
    return int(n_boot)


def _resample(w_ij: np.ndarray, n: np.ndarray, n_boot: int, seeds: list) -> np.ndarray:
    """Binomial draws of wins[I, J]: (G, K, n_boot) floats, matrix g drawn from seeds[g].

    ``w_ij``, ``n``: (K, G) observed wins[I, J] and comparison counts.  Each matrix
    has its own random stream, so its replicates do not depend on how the stack is
    split into units of work.
    """
    p = np.divide(w_ij, n, out=np.zeros_like(w_ij), where=n > 0)
    counts = n.astype(np.int64)
    out = np.empty((n.shape[1], n.shape[0], n_boot))
    for g, seed in enumerate(seeds):
        rng = np.random.default_rng(seed)
        # Replicates on the last axis: consecutive draws share (n, p), which lets the
        # binomial generator reuse its set-up (several times faster than pairs last).
        out[g] = rng.binomial(counts[:, g, None], p[:, g, None], size=(len(n), n_boot))
    return out


def _matrix_seeds(seed, n_matrices: int) -> list:
    """Child g of ``SeedSequence(seed)`` for each matrix g, built without spawning so a
    SeedSequence passed in is not advanced (the same seed object, the same draws)."""
    if isinstance(seed, np.random.Generator):
        raise TypeError("seed must be an int, a sequence of ints or a SeedSequence, not a Generator")
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return [
        np.random.SeedSequence(root.entropy, spawn_key=root.spawn_key + (g,), pool_size=root.pool_size)
        for g in range(n_matrices)
    ]


def bootstrap_wins(wins, n_boot: int, seed=0) -> np.ndarray:
    """The resampled win matrices behind :func:`bootstrap_bradley_terry`: ``(..., n_boot, P, P)``.

    For each unordered pair with ``n_ij > 0``, ``wins[i, j]* ~ Binomial(n_ij,
    wins[i, j] / n_ij)`` and ``wins[j, i]* = n_ij - wins[i, j]*``.  Same seed, same
    draws as the bootstrap fit.
    """
    arr = _as_wins(wins, integer=True)
    n_boot = _check_n_boot(n_boot)
    batch_shape, P = arr.shape[:-2], arr.shape[-1]
    w_ij, w_ji = to_pairs(arr.reshape(-1, P, P))
    n = w_ij + w_ji
    draws = _resample(w_ij, n, n_boot, _matrix_seeds(seed, n.shape[1]))
    draws = draws.transpose(1, 0, 2).reshape(len(n), -1)
    boot = from_pairs(draws, np.repeat(n, n_boot, axis=1) - draws, P)
    return boot.reshape(batch_shape + (n_boot, P, P))


def bootstrap_bradley_terry(
    wins,
    n_boot: int,
    seed=0,
    *,
    names: Sequence[str] | None = None,
    n_threads: int | None = 1,
) -> np.ndarray:
    """Bootstrap Bradley-Terry strengths: ``(n_boot, P)`` for one matrix.

    Each replicate resamples every compared pair binomially with its observed win
    rate and fixed count (see :func:`bootstrap_wins`) and is refitted.  A
    ``(..., P, P)`` stack (e.g. checkpoints x judges) is resampled and fitted in one
    vectorised pass and gives ``(..., n_boot, P)``.

    Deterministic for a given ``seed`` (an int, a sequence of ints such as
    ``[seed, checkpoint]``, or a ``numpy.random.SeedSequence``):
    matrix ``g`` of the flattened stack draws from child ``g`` of
    ``SeedSequence(seed)``, so the first matrix of a stack gets the same replicates
    as when bootstrapped alone.  ``n_threads`` (``None``: all usable CPUs; one by
    default, as pipeline jobs already run side by side) does not change the result.

    Every replicate agrees with :func:`fit_bradley_terry` on its resampled matrix:
    replicates start from their matrix's point estimate, take one Newton step that
    shares that matrix's Hessian, and finish with :func:`fit_bradley_terry_batch`'s
    Newton/MM scheme.
    """
    arr = _as_wins(wins, integer=True)
    n_boot = _check_n_boot(n_boot)
    batch_shape, P = arr.shape[:-2], arr.shape[-1]
    _check_names(names, P)
    _check_connected(arr, names)
    if P == 1:
        return np.ones(batch_shape + (n_boot, 1))
    w_ij, w_ji = to_pairs(arr.reshape(-1, P, P))
    n = w_ij + w_ji
    G = n.shape[1]
    seeds = _matrix_seeds(seed, G)
    point, _ = _fit_pairs(w_ij, w_ji, P)
    theta0 = np.log(np.maximum(point, 1e-300))
    strengths = np.empty((G, n_boot, P))
    per_unit = max(1, _newton.block_size(P) // n_boot)  # matrices per unit of work

    def task(unit: int, work: _newton.Workspace) -> int:
        gs = slice(unit * per_unit, min((unit + 1) * per_unit, G))
        draws = _resample(w_ij[:, gs], n[:, gs], n_boot, seeds[gs])  # (g, K, n_boot)
        theta1 = _newton.shared_first_step(theta0[:, gs], n[:, gs], w_ij[:, gs], draws, P)
        boot_ij = np.ascontiguousarray(draws.transpose(1, 0, 2)).reshape(len(n), -1)
        boot_ji = np.repeat(n[:, gs], n_boot, axis=1) - boot_ij
        fitted, count = _fit_pairs(boot_ij, boot_ji, P, theta1, work=work)
        strengths[gs] = fitted.T.reshape(-1, n_boot, P)
        return count

    not_converged = _run_units(task, -(-G // per_unit), P, n_threads)
    _warn_not_converged(not_converged, G * n_boot)
    return strengths.reshape(batch_shape + (n_boot, P))


# -------------------------------------------------------------------- reporting


def bt_scores(strengths) -> np.ndarray:
    """Reported Bradley-Terry score ``s = 100 b`` (strengths sum to 1, scores to 100)."""
    return 100.0 * np.asarray(strengths, dtype=np.float64)


def bt_confidence_intervals(boot_strengths, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Percentile bootstrap intervals of the score ``s = 100 b``.

    ``boot_strengths`` has shape ``(..., n_boot, P)`` (replicates on the second to
    last axis); returns ``(lower, upper)``, each ``(..., P)``, the ``(1 - level) / 2``
    and ``(1 + level) / 2`` quantiles (linear interpolation).
    """
    if not 0.0 < level < 1.0:
        raise ConfigError(f"level must lie strictly between 0 and 1, got {level}")
    boot = np.asarray(boot_strengths, dtype=np.float64)
    if boot.ndim < 2:
        raise ValueError(f"boot_strengths must have shape (..., n_boot, P), got {boot.shape}")
    tail = 50.0 * (1.0 - level)
    lower, upper = np.percentile(bt_scores(boot), [tail, 100.0 - tail], axis=-2)
    return lower, upper


def bt_ci_width(boot_strengths, level: float):
    """Mean over policies of the percentile-interval width of ``s`` (score points).

    A float for ``(n_boot, P)`` input, an array ``(...)`` for ``(..., n_boot, P)``.
    """
    lower, upper = bt_confidence_intervals(boot_strengths, level)
    width = (upper - lower).mean(axis=-1)
    return float(width) if np.ndim(width) == 0 else width
