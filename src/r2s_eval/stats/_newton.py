"""Batched Newton solver for Bradley-Terry maximum likelihood, in pair form.

Works on ``theta = log b``.  For pair ``k`` with ``n_k`` comparisons and
``p_k = sigmoid(theta_I - theta_J)`` the log-likelihood has gradient
``D^T (w_ij - n p)`` and negative Hessian ``D^T diag(n p (1 - p)) D``, a weighted
graph Laplacian (``D`` the pair/policy incidence matrix).  It is concave, so
Newton converges quadratically from a nearby start; each column (matrix) stops on
its own once its step is negligible.

Only *regular* columns go through Newton: those whose maximum is attained at
finite theta once never-winning policies are set to zero (see
:func:`regular_columns`).  The caller gives the others to MM.
"""

from __future__ import annotations

import numpy as np

from r2s_eval.stats._pairs import incidence, pair_index, policy_totals, transitive_closure

# Stopping rule.  The logistic function's third derivative is bounded by its
# second, so Hessians at points a distance d apart differ by a factor of about
# exp(2 d).  The error left by a Newton step of max-norm delta is then about
# delta**2 and that of a chord step about delta times the distance to the point
# where its Hessian was taken; ERROR_SCALE adds a safety factor.  TARGET_ERROR in
# theta is far below the promised 1e-6 agreement with MM on the strengths.
ERROR_SCALE = 10.0
TARGET_ERROR = 1e-8
MAX_ITER = 100
# Far from the optimum the likelihood is nearly flat in saturated directions and a
# raw Newton step can overshoot; steps are scaled down to this max-norm in theta.
MAX_STEP = 2.0
# Starting points are clipped to this spread in theta so a near-zero starting
# strength cannot cost dozens of clipped steps.
INIT_SPREAD = 30.0
# Columns per block: one Newton step's temporaries then stay in cache.
BLOCK = 2048
WORKSPACE_BYTES = 32 * 2**20


def regular_columns(w_ij: np.ndarray, w_ji: np.ndarray, P: int) -> np.ndarray:
    """Columns whose maximum-likelihood strengths exist, up to never-winning policies.

    MM sends a policy with no wins to exactly zero in one step; the other strengths
    then converge to the maximum of the likelihood without it, which exists iff the
    "beat" graph on the remaining policies is strongly connected.  Elsewhere MM
    drifts towards a boundary and its value after the last iteration is the answer.
    Assumes connected comparison graphs.
    """
    I, J = pair_index(P)
    # Fast path: every compared pair went both ways.
    regular = (((w_ij > 0) & (w_ji > 0)) | ((w_ij == 0) & (w_ji == 0))).all(axis=0)
    slow = np.flatnonzero(~regular)
    if slow.size:
        a_ij, a_ji = w_ij[:, slow], w_ji[:, slow]
        live = policy_totals(a_ij, a_ji, P) > 0
        adj = np.zeros((P, P, slow.size), dtype=bool)
        adj[I, J] = a_ij > 0
        adj[J, I] = a_ji > 0
        needed = live[:, None] & live[None, :]
        reach = transitive_closure(adj & needed)
        regular[slow] = (reach | ~needed).all(axis=(0, 1))
    return regular


def factor_spd(A: np.ndarray, scratch: np.ndarray | None = None) -> np.ndarray:
    """LU-factor a (R, R, B) stack of symmetric positive-definite matrices in place.

    Gaussian elimination without pivoting (stable for SPD), vectorised over the
    batch axis: for the handful of policies of a ranking this is far faster than
    one LAPACK call per matrix.  Multipliers are stored below the diagonal.
    ``scratch`` (at least (R-1, R-1, B)) avoids temporaries in the hot loop.
    """
    R = A.shape[0]
    if scratch is None:
        scratch = np.empty((max(R - 1, 1), max(R - 1, 1), A.shape[2]))
    for k in range(R - 1):
        A[k + 1 :, k] /= A[k, k]
        update = scratch[: R - k - 1, : R - k - 1]
        np.multiply(A[k + 1 :, k][:, None], A[k, k + 1 :][None], out=update)
        A[k + 1 :, k + 1 :] -= update
    return A


def solve_factored(LU: np.ndarray, x: np.ndarray, scratch: np.ndarray | None = None) -> np.ndarray:
    """Solve in place with factors from :func:`factor_spd`; ``x`` (R, B) holds the right-hand side."""
    R = LU.shape[0]
    if scratch is None:
        scratch = np.empty((max(R - 1, 1), LU.shape[2]))
    for k in range(R - 1):
        update = scratch[: R - k - 1]
        np.multiply(LU[k + 1 :, k], x[k], out=update)
        x[k + 1 :] -= update
    row = scratch[0]
    for k in range(R - 1, -1, -1):
        for j in range(k + 1, R):
            np.multiply(LU[k, j], x[j], out=row)
            x[k] -= row
        x[k] /= LU[k, k]
    return x


def _fill_laplacian(A: np.ndarray, info: np.ndarray, degree: np.ndarray, live: np.ndarray | None) -> None:
    """Write the negative Hessian, the information-weighted graph Laplacian, into A.

    Theta is defined up to a shift and the gradient sums to zero.  Without held-out
    policies (``live is None``) A is (P-1, P-1): the last policy's step is pinned to
    zero, leaving a positive-definite system.  Otherwise A is (P, P): a rank-one
    term on the live policies pins the step to sum zero and held-out policies get a
    unit diagonal, hence a zero step.
    """
    R = A.shape[0]
    P = degree.shape[0]
    I, J = pair_index(P)
    for k in range(len(I)):
        if J[k] < R:
            np.negative(info[k], out=A[I[k], J[k]])
            A[J[k], I[k]] = A[I[k], J[k]]
    for i in range(R):
        A[i, i] = degree[i]
    if live is not None:
        # Any positive weight pins the shift; +1 keeps it positive when a single
        # live policy is left with no comparisons.
        shift = degree.sum(axis=0) / P + 1.0
        for i in range(P):
            for j in range(P):
                A[i, j] += shift * live[i] * live[j]
            A[i, i] += 1.0 - live[i]


def _step_size(step: np.ndarray) -> np.ndarray:
    """Max-norm of each column's step, scaling down the steps that exceed MAX_STEP."""
    size = np.maximum(step.max(axis=0), -step.min(axis=0))
    big = size > MAX_STEP
    if big.any():
        step[:, big] *= MAX_STEP / size[big]
    return size


def block_size(P: int) -> int:
    """Columns per block for P policies: BLOCK, or fewer when many policies make a
    column's workspace large."""
    return int(min(BLOCK, max(64, WORKSPACE_BYTES // (8 * Workspace.rows_per_column(P)))))


def newton(
    w_ij: np.ndarray,
    w_ji: np.ndarray,
    P: int,
    theta0: np.ndarray | None = None,
    work: "Workspace | None" = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Strengths (P, B) of regular columns and a converged flag (B,)."""
    B = w_ij.shape[1]
    block = block_size(P)
    strengths = np.empty((P, B))
    converged = np.empty(B, dtype=bool)
    if work is None or work.P != P:
        work = Workspace(P)
    for start in range(0, B, block):
        cols = slice(start, min(start + block, B))
        init = None if theta0 is None else theta0[:, cols]
        strengths[:, cols], converged[cols] = _newton_block(
            w_ij[:, cols], w_ji[:, cols], P, init, work
        )
    return strengths, converged


class Workspace:
    """Flat buffers reused by every block and Newton iteration of one thread.

    Large temporaries come from fresh memory on each allocation, and the page
    faults cost more than the arithmetic; so the hot loop writes into these
    buffers instead.  Per-column state lives in one (rows, m) array that is
    compacted into its twin when columns converge.
    """

    def __init__(self, P: int):
        K = P * (P - 1) // 2
        block = block_size(P)
        self.P, self.K, self.block = P, K, block
        self.state_rows = 2 * P + 2 * K + 2 + P * P  # theta, w_ij, n, last step, column, live, LU
        self.state = [np.empty(self.state_rows * block), np.empty(self.state_rows * block)]
        self.pairs = np.empty(3 * K * block)
        self.policies = np.empty(3 * P * block)
        self.solve = np.empty((P * P + P) * block)

    @staticmethod
    def rows_per_column(P: int) -> int:
        K = P * (P - 1) // 2
        return 2 * (2 * P + 2 * K + 2 + P * P) + 3 * K + 3 * P + P * P + P

    def views(self, m: int, R: int, which: int) -> dict[str, np.ndarray]:
        P, K = self.P, self.K
        state = self.state[which][: self.state_rows * m].reshape(self.state_rows, m)
        rows = np.cumsum([0, P, K, K, 1, 1, P, R * R])
        names = ["theta", "w", "n", "last", "column", "live", "LU"]
        view = {name: state[rows[i] : rows[i + 1]] for i, name in enumerate(names)}
        view["LU"] = view["LU"].reshape(R, R, m)
        view["state"] = state[: rows[-1]]
        pairs = self.pairs[: 3 * K * m].reshape(3, K, m)
        policies = self.policies[: 3 * P * m].reshape(3, P, m)
        view.update(p=pairs[0], expected=pairs[1], tmp=pairs[2])
        view.update(grad=policies[0], step=policies[1], degree=policies[2])
        view["factor_scratch"] = self.solve[: P * P * m].reshape(P, P, m)[: max(R - 1, 1), : max(R - 1, 1)]
        view["solve_scratch"] = self.solve[P * P * m : (P * P + P) * m].reshape(P, m)
        return view


def _newton_block(
    w_ij: np.ndarray, w_ji: np.ndarray, P: int, theta0: np.ndarray | None, work: Workspace
) -> tuple[np.ndarray, np.ndarray]:
    I, J = pair_index(P)
    D = incidence(P)
    D_neg, D_t, D_abs_t = -D, D.T, np.abs(D).T
    B = w_ij.shape[1]
    wins = policy_totals(w_ij, w_ji, P)
    # Never-winning policies are held out (their pairs removed, strength exactly
    # zero), as MM does in its first step.
    zero = wins == 0
    has_zero = bool(zero.any())
    R = P if has_zero else P - 1
    if has_zero:
        pair_out = zero[I] | zero[J]
        w_ij = np.where(pair_out, 0.0, w_ij)
        w_ji = np.where(pair_out, 0.0, w_ji)

    which, m = 0, B
    v = work.views(m, R, which)
    v["w"][...] = w_ij
    np.add(w_ij, w_ji, out=v["n"])
    v["column"][0] = np.arange(B)
    v["live"][...] = ~zero
    if theta0 is None:
        # Log-odds of each policy's win rate: close to the optimum for balanced designs.
        losses = policy_totals(w_ji, w_ij, P)
        v["theta"][...] = np.log((wins + 0.5) / (losses + 0.5))
    else:
        v["theta"][...] = theta0
    theta = v["theta"]
    if has_zero:
        theta[zero] = 0.0
    np.maximum(theta, theta.max(axis=0) - INIT_SPREAD, out=theta)

    out_theta = np.empty((P, B))
    converged = np.zeros(B, dtype=bool)
    finished = np.zeros(m, dtype=bool)
    for iteration in range(MAX_ITER):
        theta, p, expected, tmp = v["theta"], v["p"], v["expected"], v["tmp"]
        np.matmul(D_neg, theta, out=p)
        with np.errstate(over="ignore"):
            np.exp(p, out=p)
        p += 1.0
        np.reciprocal(p, out=p)  # P(policy I[k] beats J[k])
        np.multiply(v["n"], p, out=expected)
        np.subtract(v["w"], expected, out=tmp)
        np.matmul(D_t, tmp, out=v["grad"])
        # Full Newton steps alternate with chord steps that reuse the last factors:
        # near the optimum a chord step costs half as much and gains nearly as much.
        full = iteration % 2 == 0
        if full:
            np.multiply(expected, p, out=tmp)
            np.subtract(expected, tmp, out=tmp)  # Fisher information n p (1 - p)
            np.matmul(D_abs_t, tmp, out=v["degree"])
            _fill_laplacian(v["LU"], tmp, v["degree"], v["live"] if has_zero else None)
            factor_spd(v["LU"], v["factor_scratch"])
        step = v["step"]
        step[...] = v["grad"]
        if not has_zero:
            step[R:] = 0.0
        solve_factored(v["LU"], step[:R], v["solve_scratch"])
        size = _step_size(step)
        theta += step
        if full:
            v["last"][0] = size
            error = ERROR_SCALE * size * size
        else:
            # The chord Hessian was taken one full step away.
            error = ERROR_SCALE * v["last"][0] * size
        finished |= error < TARGET_ERROR
        # Converged columns may take further (harmless) steps until enough of them
        # have finished to make compacting the state worth its copy.
        n_finished = int(finished.sum())
        if n_finished == m or (n_finished and 2 * n_finished >= m):
            columns = v["column"][0, finished].astype(np.int64)
            out_theta[:, columns] = theta[:, finished]
            converged[columns] = True
            keep = np.flatnonzero(~finished)
            if keep.size == 0:
                break
            old = v["state"]
            which, m = 1 - which, keep.size
            v = work.views(m, R, which)
            np.take(old, keep, axis=1, out=v["state"], mode="clip")
            finished = np.zeros(m, dtype=bool)
    else:
        columns = v["column"][0].astype(np.int64)
        out_theta[:, columns] = v["theta"]
        converged[columns] = finished
    return to_strengths(out_theta, zero), converged


def to_strengths(theta: np.ndarray, zero: np.ndarray | None = None) -> np.ndarray:
    """Normalised strengths exp(theta) / sum, with ``zero`` policies set to exactly 0."""
    theta = np.where(zero, -np.inf, theta) if zero is not None else theta.copy()
    theta -= theta.max(axis=0)
    strengths = np.exp(theta)
    strengths /= strengths.sum(axis=0)
    return strengths


def shared_first_step(
    theta0: np.ndarray, n: np.ndarray, w_point: np.ndarray, w_boot: np.ndarray, P: int
) -> np.ndarray:
    """One Newton step for all bootstrap replicates of each matrix at once.

    Replicates keep their matrix's comparison counts ``n``, so at the common start
    ``theta0`` (the point estimate) they share the Hessian and their gradients are
    linear in the resampled wins: the first step costs one small matrix product
    per matrix instead of a factorisation per replicate.

    theta0: (P, G) point estimates in log space (never-winners at any value);
    n, w_point: (K, G) counts and point-estimate wins[I, J]; w_boot: (G, K, R)
    resampled wins[I, J].  Returns theta after the step as (P, G * R), replicate
    ``r`` of matrix ``g`` in column ``g * R + r``.
    """
    I, J = pair_index(P)
    D = incidence(P)
    G, R = n.shape[1], w_boot.shape[2]
    w_ji_point = n - w_point
    zero = policy_totals(w_point, w_ji_point, P) == 0  # (P, G)
    theta0 = np.where(zero, 0.0, theta0)
    keep = ~(zero[I] | zero[J])  # pairs that take part once never-winners are held out
    with np.errstate(over="ignore"):
        p0 = 1.0 / (1.0 + np.exp(-(D @ theta0)))
    n_kept = np.where(keep, n, 0.0)
    info = n_kept * p0 * (1.0 - p0)
    # Invert the gauge-fixed Hessian of every matrix (G of them, not G * R).
    live = (~zero).astype(np.float64)
    A = np.einsum("kp,kq,kg->gpq", D, D, info)
    degree_mean = np.einsum("gpp->g", A) / P
    A += (degree_mean + 1.0)[:, None, None] * live.T[:, :, None] * live.T[:, None, :]
    A[:, np.arange(P), np.arange(P)] += zero.T
    # Where the point estimate has no finite maximum the Hessian can be singular:
    # those replicates simply start from the point estimate.
    regular = regular_columns(w_point, w_ji_point, P)
    A[~regular] = np.eye(P)
    # gain @ (w - n p0): pairs with a never-winner (and irregular matrices) get no weight.
    gain = np.linalg.solve(A, np.broadcast_to(D.T, (G, P, len(I))) * (keep & regular).T[:, None, :])
    step = np.matmul(gain, w_boot)  # (G, P, R)
    step -= np.matmul(gain, (n_kept * p0).T[:, :, None])
    theta = np.ascontiguousarray(step.transpose(1, 0, 2)).reshape(P, G * R)
    _step_size(theta)
    theta += np.repeat(theta0, R, axis=1)
    return theta
