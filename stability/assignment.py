"""The linear assignment problem: the permutation of least total cost.

:func:`linear_assignment` solves ``min_pi sum_i C[i, pi(i)]`` for a square cost matrix by the
shortest-augmenting-path form of the Hungarian algorithm (Kuhn 1955, Munkres 1957; with the dual
potentials of Jonker and Volgenant 1987), ``O(n^3)``, each inner step one vector operation over the
columns.  It is what :func:`scipy.optimize.linear_sum_assignment` solves (and the tests compare with
it); it exists because the Floquet engine pairs the spectra of two refinements on every solve of a
large system and importing :mod:`scipy.optimize` costs ~0.15 s, more than a whole Floquet solve of a
few dozen states.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["linear_assignment"]

#: Up to this size the same algorithm runs on Python lists (a few microseconds; numpy's per-call
#: overhead would dominate): the Floquet engine pairs the spectra of small systems on every solve.
SMALL = 12


def linear_assignment(cost: np.ndarray) -> np.ndarray:
    """Columns ``cols`` minimising ``sum_i cost[i, cols[i]]`` over all permutations.

    Parameters
    ----------
    cost : array_like, shape (n, n)
        Finite real costs.

    Returns
    -------
    ndarray of int, shape (n,)
        ``cols[i]`` is the column assigned to row ``i`` (a permutation of ``0 .. n - 1``).

    Raises
    ------
    ValueError
        For a non-square or non-finite cost matrix.

    Notes
    -----
    Each row starts on its cheapest column where no earlier row took it (the potentials ``u`` the
    row minima, ``v = 0``: dual feasible, those edges tight); the other rows are added one at a time;
    each addition grows a tree of alternating paths from the new row
    by Dijkstra's rule on the reduced costs ``cost[i, j] - u[i] - v[j] >= 0`` until it reaches a free
    column, then flips the path.  The potentials stay dual feasible, so the final assignment is
    optimal (complementary slackness).  Ties are broken by the lowest column index.
    """
    C = np.asarray(cost, dtype=float)
    if C.ndim != 2 or C.shape[0] != C.shape[1]:
        raise ValueError(f"the cost matrix must be square, got shape {C.shape}")
    if not np.isfinite(C).all():
        raise ValueError("the cost matrix has non-finite entries")
    n = C.shape[0]
    if n <= SMALL:
        return np.array(_small_assignment(C.tolist()), dtype=np.intp)
    # 1-based columns as in the textbook form: column 0 is the virtual root of each tree
    u = np.zeros(n + 1)
    v = np.zeros(n + 1)
    row_of = np.zeros(n + 1, dtype=np.intp)  # row_of[j]: row (1-based) assigned to column j, 0 = free
    way = np.zeros(n + 1, dtype=np.intp)
    # start: u = row minima (dual feasible with v = 0), each row on its cheapest column where that
    # column is not taken by an earlier row (tight edges); only the other rows are augmented
    nearest = C.argmin(axis=1)
    u[1:] = C[np.arange(n), nearest]
    taken, first = np.unique(nearest, return_index=True)
    row_of[taken + 1] = first + 1
    pending = np.setdiff1d(np.arange(1, n + 1), first + 1)
    for i in pending.tolist():
        row_of[0] = i
        j0 = 0
        minv = np.full(n + 1, np.inf)
        used = np.zeros(n + 1, dtype=bool)
        while True:
            used[j0] = True
            i0 = row_of[j0]
            reduced = C[i0 - 1] - u[i0] - v[1:]
            free = ~used[1:]
            better = free & (reduced < minv[1:])
            minv[1:][better] = reduced[better]
            way[1:][better] = j0
            candidates = np.where(free, minv[1:], np.inf)
            j1 = int(np.argmin(candidates)) + 1
            delta = candidates[j1 - 1]
            u[row_of[used]] += delta
            v[used] -= delta
            minv[~used] -= delta
            j0 = j1
            if row_of[j0] == 0:
                break
        while j0:  # flip the alternating path back to the root
            j1 = way[j0]
            row_of[j0] = row_of[j1]
            j0 = j1
    cols = np.empty(n, dtype=np.intp)
    cols[row_of[1:] - 1] = np.arange(n)
    return cols


def _small_assignment(C: list) -> list:
    """:func:`linear_assignment` of a small square cost matrix given as lists (same algorithm, same
    ties)."""
    n = len(C)
    if n == 0:
        return []
    inf = math.inf
    u = [0.0] * (n + 1)
    v = [0.0] * (n + 1)
    row_of = [0] * (n + 1)
    way = [0] * (n + 1)
    pending = []
    for i, row in enumerate(C, start=1):
        j = min(range(n), key=row.__getitem__)
        u[i] = row[j]
        if row_of[j + 1] == 0:
            row_of[j + 1] = i
        else:
            pending.append(i)
    for i in pending:
        row_of[0] = i
        j0 = 0
        minv = [inf] * (n + 1)
        used = [False] * (n + 1)
        while True:
            used[j0] = True
            i0 = row_of[j0]
            row, ui = C[i0 - 1], u[i0]
            delta, j1 = inf, 0
            for j in range(1, n + 1):
                if not used[j]:
                    cur = row[j - 1] - ui - v[j]
                    if cur < minv[j]:
                        minv[j], way[j] = cur, j0
                    if minv[j] < delta:
                        delta, j1 = minv[j], j
            for j in range(n + 1):
                if used[j]:
                    u[row_of[j]] += delta
                    v[j] -= delta
                else:
                    minv[j] -= delta
            j0 = j1
            if row_of[j0] == 0:
                break
        while j0:
            j1 = way[j0]
            row_of[j0] = row_of[j1]
            j0 = j1
    cols = [0] * n
    for j in range(1, n + 1):
        cols[row_of[j] - 1] = j - 1
    return cols
