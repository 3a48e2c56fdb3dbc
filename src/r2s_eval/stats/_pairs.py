"""Pair form of a batch of win matrices.

A batch of B matrices over P policies is held as (K, B) arrays, one row per
unordered pair ``k = (I[k], J[k])`` with ``I < J`` and one column per matrix:
``w_ij = wins[I, J]`` and ``w_ji = wins[J, I]``.  Every vectorised step then runs
along a long contiguous batch axis, and only compared pairs carry data.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=None)
def pair_index(P: int) -> tuple[np.ndarray, np.ndarray]:
    I, J = np.triu_indices(P, 1)
    I.flags.writeable = False
    J.flags.writeable = False
    return I, J


@lru_cache(maxsize=None)
def incidence(P: int) -> np.ndarray:
    """(K, P) matrix with +1 at I[k] and -1 at J[k]: ``incidence @ theta`` gives theta_I - theta_J."""
    I, J = pair_index(P)
    D = np.zeros((len(I), P))
    D[np.arange(len(I)), I] = 1.0
    D[np.arange(len(I)), J] = -1.0
    D.flags.writeable = False
    return D


def to_pairs(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B, P, P) matrices -> (K, B) arrays of wins[I, J] and wins[J, I]."""
    I, J = pair_index(flat.shape[-1])
    return np.ascontiguousarray(flat[:, I, J].T), np.ascontiguousarray(flat[:, J, I].T)


def from_pairs(w_ij: np.ndarray, w_ji: np.ndarray, P: int) -> np.ndarray:
    """(K, B) pair arrays -> (B, P, P) matrices."""
    I, J = pair_index(P)
    out = np.zeros((w_ij.shape[1], P, P))
    out[:, I, J] = w_ij.T
    out[:, J, I] = w_ji.T
    return out


def policy_totals(x_ij: np.ndarray, x_ji: np.ndarray, P: int) -> np.ndarray:
    """Per-policy sums ``sum_j x[i, j]`` of a pair quantity given both orientations: (P, B).

    Accumulates pair by pair in a fixed order, so a column's result does not
    depend on the other columns in the batch.
    """
    I, J = pair_index(P)
    out = np.zeros((P, x_ij.shape[1]))
    for k in range(len(I)):
        out[I[k]] += x_ij[k]
        out[J[k]] += x_ji[k]
    return out


def transitive_closure(adj: np.ndarray) -> np.ndarray:
    """Reachability for a (P, P, B) stack of boolean adjacency matrices (Floyd-Warshall)."""
    reach = adj | np.eye(adj.shape[0], dtype=bool)[:, :, None]
    for k in range(adj.shape[0]):
        reach |= reach[:, k : k + 1] & reach[k : k + 1, :]
    return reach
