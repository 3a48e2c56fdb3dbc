"""Least squares on residuals computed by rendering.

A rendered image changes in whole pixels and 8-bit levels, so the Jacobian's finite differences
need steps of a size that moves something visible; scipy's relative steps shrink to nothing at a
zero start. ``fit`` gives scipy's solver forward differences of fixed steps instead, and reuses
the residual of the point it was just asked for.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.optimize import OptimizeResult, least_squares


def fit(residuals: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, steps: float | Sequence[float],
        **options) -> OptimizeResult:
    """``scipy.optimize.least_squares`` of ``residuals`` from ``x0`` with a forward-difference
    Jacobian of absolute ``steps`` (one per parameter, or one for all); ``options`` go to scipy."""
    x0 = np.asarray(x0, float)
    steps = np.broadcast_to(np.asarray(steps, float), x0.shape)
    last: dict[bytes, np.ndarray] = {}

    def fun(x):
        key = np.asarray(x, float).tobytes()
        if key not in last:
            last.clear()
            last[key] = np.asarray(residuals(np.asarray(x, float)), float)
        return last[key]

    def jac(x):
        f0 = fun(x)
        J = np.empty((f0.size, x.size))
        for i in range(x.size):
            moved = np.array(x, float)
            moved[i] += steps[i]
            J[:, i] = (np.asarray(residuals(moved), float) - f0) / steps[i]
        return J

    return least_squares(fun, x0, jac=jac, **options)
