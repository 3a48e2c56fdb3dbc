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


@lru_cache(maxsize=None)
def _role_matrices(P: int) -> tuple[np.ndarray, np.ndarray]:
    """(P, K) indicators of the pairs where each policy is I, and where it is J."""
    I, J = pair_index(P)
    as_i = np.zeros((P, len(I)))
    as_j = np.zeros((P, len(I)))
    as_i[I, np.arange(len(I))] = 1.0
    as_j[J, np.arange(len(I))] = 1.0
    as_i.flags.writeable = False
    as_j.flags.writeable = False
    return as_i, as_j


def policy_totals(x_ij: np.ndarray, x_ji: np.ndarray, P: int) -> np.ndarray:
    """Per-policy sums ``sum_j x[i, j]`` of a pair quantity given both orientations: (P, B)."""
    as_i, as_j = _role_matrices(P)
    out = as_i @ x_ij
    out += as_j @ x_ji
    return out


def transitive_closure(adj: np.ndarray) -> np.ndarray:
    """Reachability for a (P, P, B) stack of boolean adjacency matrices (Floyd-Warshall)."""
    reach = adj | np.eye(adj.shape[0], dtype=bool)[:, :, None]
    for k in range(adj.shape[0]):
        reach |= reach[:, k : k + 1] & reach[k : k + 1, :]
    return reach
