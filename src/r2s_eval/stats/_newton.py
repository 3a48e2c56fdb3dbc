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
TARGET_ERROR = 1e-9
MAX_ITER = 100
# Far from the optimum the likelihood is nearly flat in saturated directions and a
# raw Newton step can overshoot; steps are scaled down to this max-norm in theta.
MAX_STEP = 2.0
# Starting points are clipped to this spread in theta so a near-zero starting
# strength cannot cost dozens of clipped steps.
INIT_SPREAD = 30.0
# Columns per block: one Newton step's temporaries then stay in cache.
BLOCK = 4096


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


def factor_spd(A: np.ndarray) -> np.ndarray:
    """LU-factor a (R, R, B) stack of symmetric positive-definite matrices in place.

    Gaussian elimination without pivoting (stable for SPD), vectorised over the
    batch axis: for the handful of policies of a ranking this is far faster than
    one LAPACK call per matrix.  Multipliers are stored below the diagonal.
    """
    R = A.shape[0]
    for k in range(R - 1):
        A[k + 1 :, k] /= A[k, k]
        A[k + 1 :, k + 1 :] -= A[k + 1 :, k][:, None] * A[k, k + 1 :][None]
    return A


def solve_factored(LU: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Solve with factors from :func:`factor_spd`; ``g`` is (R, B)."""
    R = g.shape[0]
    x = g.copy()
    for k in range(R - 1):
        x[k + 1 :] -= LU[k + 1 :, k] * x[k]
    for k in range(R - 1, -1, -1):
        if k + 1 < R:
            x[k] -= (LU[k, k + 1 :] * x[k + 1 :]).sum(axis=0)
        x[k] /= LU[k, k]
    return x


def solve_spd(A: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Solve A x = g for a (R, R, B) stack of SPD matrices (overwrites A)."""
    return solve_factored(factor_spd(A), g)


def _laplacian_factors(info: np.ndarray, P: int, held_out: np.ndarray | None) -> np.ndarray:
    """Factors of the negative Hessian, the information-weighted graph Laplacian L.

    Theta is defined up to a shift and the gradient sums to zero.  Without held-out
    policies the last policy's step is pinned to zero, leaving a (P-1)-dimensional
    positive-definite system.  Otherwise a rank-one term on the live policies pins
    the step to sum zero and held-out policies get a unit diagonal (zero step).
    """
    I, J = pair_index(P)
    B = info.shape[1]
    degree = np.abs(incidence(P)).T @ info
    if held_out is None:
        R = P - 1
        inner = J < R
        A = np.zeros((R, R, B))
        A[I[inner], J[inner]] = -info[inner]
        A[J[inner], I[inner]] = -info[inner]
        A[np.arange(R), np.arange(R)] = degree[:R]
        return factor_spd(A)
    A = np.empty((P, P, B))
    A[I, J] = -info
    A[J, I] = -info
    A[np.arange(P), np.arange(P)] = degree
    live = (~held_out).astype(np.float64)
    A += (degree.sum(axis=0) / P) * live[:, None] * live[None, :]
    A[np.arange(P), np.arange(P)] += held_out
    return factor_spd(A)


def _laplacian_solve(LU: np.ndarray, grad: np.ndarray) -> np.ndarray:
    R, P = LU.shape[0], grad.shape[0]
    if R == P:
        return solve_factored(LU, grad)
    step = np.zeros_like(grad)
    step[:R] = solve_factored(LU, grad[:R])
    return step


def _clip_step(step: np.ndarray) -> np.ndarray:
    """Max-norm of each column's step, scaling down the steps that exceed MAX_STEP."""
    size = np.abs(step).max(axis=0)
    big = size > MAX_STEP
    if big.any():
        step[:, big] *= MAX_STEP / size[big]
    return size


def newton(
    w_ij: np.ndarray, w_ji: np.ndarray, P: int, theta0: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Strengths (P, B) of regular columns and a converged flag (B,)."""
    B = w_ij.shape[1]
    strengths = np.empty((P, B))
    converged = np.empty(B, dtype=bool)
    for start in range(0, B, BLOCK):
        cols = slice(start, min(start + BLOCK, B))
        init = None if theta0 is None else theta0[:, cols]
        strengths[:, cols], converged[cols] = _newton_block(w_ij[:, cols], w_ji[:, cols], P, init)
    return strengths, converged


def _newton_block(
    w_ij: np.ndarray, w_ji: np.ndarray, P: int, theta0: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    I, J = pair_index(P)
    D = incidence(P)
    B = w_ij.shape[1]
    wins = policy_totals(w_ij, w_ji, P)
    # Never-winning policies are held out (their pairs removed, strength exactly
    # zero), as MM does in its first step.
    zero = zero_all = wins == 0
    held_out = None
    if zero.any():
        held_out = zero
        pair_out = zero[I] | zero[J]
        w_ij = np.where(pair_out, 0.0, w_ij)
        w_ji = np.where(pair_out, 0.0, w_ji)
    n = w_ij + w_ji

    if theta0 is None:
        # Log-odds of each policy's win rate: close to the optimum for balanced designs.
        losses = policy_totals(w_ji, w_ij, P)
        theta = np.log((wins + 0.5) / (losses + 0.5))
    else:
        theta = np.array(theta0, dtype=np.float64, copy=True)
    if held_out is not None:
        theta[held_out] = 0.0
    theta = np.maximum(theta, theta.max(axis=0) - INIT_SPREAD)

    out_theta = np.empty((P, B))
    converged = np.zeros(B, dtype=bool)
    active = np.arange(B)
    LU = None
    for iteration in range(MAX_ITER):
        with np.errstate(over="ignore"):
            p = np.exp(-(D @ theta))
        p += 1.0
        np.reciprocal(p, out=p)  # P(policy I[k] beats J[k])
        expected = n * p
        grad = D.T @ (w_ij - expected)
        # Full Newton steps alternate with chord steps that reuse the last factors:
        # near the optimum a chord step costs half as much and gains nearly as much.
        full = iteration % 2 == 0
        if full:
            expected -= expected * p  # now the Fisher information n p (1 - p)
            LU = _laplacian_factors(expected, P, held_out)
        step = _laplacian_solve(LU, grad)
        size = _clip_step(step)
        theta += step
        if full:
            last_full = size
            error = ERROR_SCALE * size * size
        else:
            # The chord Hessian is off by about the last full step.
            error = ERROR_SCALE * last_full * size
        done = error < TARGET_ERROR
        if done.any():
            out_theta[:, active[done]] = theta[:, done]
            converged[active[done]] = True
            keep = ~done
            active, theta, w_ij, n = active[keep], theta[:, keep], w_ij[:, keep], n[:, keep]
            LU, last_full = LU[:, :, keep], last_full[keep]
            if held_out is not None:
                held_out = held_out[:, keep]
            if active.size == 0:
                break
    out_theta[:, active] = theta
    return to_strengths(out_theta, zero_all), converged


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
    n, w_point: (K, G) counts and point-estimate wins[I, J]; w_boot: (K, G, R).
    Returns theta after the step, (P, G, R).
    """
    I, J = pair_index(P)
    D = incidence(P)
    G = n.shape[1]
    w_ji_point = n - w_point
    zero = policy_totals(w_point, w_ji_point, P) == 0  # (P, G)
    theta0 = np.where(zero, 0.0, theta0)
    keep = ~(zero[I] | zero[J])  # pairs that take part once never-winners are held out
    p0 = 1.0 / (1.0 + np.exp(-(D @ theta0)))
    n_kept = np.where(keep, n, 0.0)
    info = n_kept * p0 * (1.0 - p0)
    # Invert the gauge-fixed Hessian of every matrix (G of them, not G * R).
    live = (~zero).astype(np.float64)
    A = np.einsum("kp,kq,kg->gpq", D, D, info)
    degree_mean = np.einsum("gpp->g", A) / P
    A += degree_mean[:, None, None] * live.T[:, :, None] * live.T[:, None, :]
    A[:, np.arange(P), np.arange(P)] += zero.T
    gain = np.linalg.solve(A, np.broadcast_to(D.T, (G, P, len(I))) * keep.T[:, None, :])  # (G, P, K)
    resid = (w_boot - (n_kept * p0)[:, :, None]) * keep[:, :, None]  # (K, G, R)
    step = np.matmul(gain, resid.transpose(1, 0, 2)).transpose(1, 0, 2)  # (P, G, R)
    flat = step.reshape(P, -1)
    _clip_step(flat)
    return theta0[:, :, None] + flat.reshape(step.shape)
