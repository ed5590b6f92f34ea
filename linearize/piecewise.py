"""Piecewise-polynomial sampling of a periodic motion that is non-smooth at known times.

A drive whose acceleration jumps (a trapezoidal velocity profile, a cam law) makes the periodic orbit
``C^1`` but not ``C^2`` at its breakpoints, and the linearisation ``P(t)`` jump there.  Equispaced
samples with trigonometric interpolation and spectral differentiation (:mod:`linearize.fourier`)
converge only algebraically on such a function; samples placed piece by piece converge spectrally on
each smooth piece again.

:class:`PiecewiseGrid` splits the period at the breakpoints (and at ``t = 0``) into pieces and puts
``m_j`` Gauss-Legendre nodes on piece ``j`` (in proportion to its length, at least
:data:`MIN_NODES`).  Two maps are built on these ``K = sum m_j`` nodes:

* **Differentiation** (``D1``, ``D2``, ``K x K``, used by the orbit's collocation exactly as the
  spectral matrices are): the derivatives at the nodes of the unique function that is a polynomial of
  degree ``m_j + 1`` on each piece, ``C^1`` across every piece boundary (periodically), and takes the
  given values at the nodes (``sum (m_j + 2)`` coefficients, ``K`` interpolation and ``2 P``
  continuity conditions).  Collocating the equations of motion at the Gauss nodes with this space is
  orthogonal collocation on finite elements (de Boor & Swartz 1973; the method of COLSYS / AUTO): a
  ``C^1`` solution with its second derivative free to jump at the boundaries, converging spectrally in
  ``m_j`` on each smooth piece.
* **Interpolation** of quantities that may jump at the boundaries (``M, C, K`` of the linearisation,
  the constraint forces and torques, the accelerations): on each piece the polynomial of degree
  ``m_j - 1`` through its own nodes (barycentric Lagrange form), no continuity imposed.

References
----------
.. [1] de Boor, C., Swartz, B., "Collocation at Gaussian points", SIAM J. Numer. Anal. 10 (1973) 582-606.
.. [2] Berrut, J.-P., Trefethen, L. N., "Barycentric Lagrange interpolation", SIAM Rev. 46 (2004) 501-517.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.polynomial import legendre

__all__ = ["PiecewiseGrid", "MIN_NODES", "piece_edges"]

#: Fewest nodes on one piece (a piece of degree ``MIN_NODES + 1``).
MIN_NODES = 4


def piece_edges(period: float, breakpoints: Sequence[float]) -> np.ndarray:
    """``[0, b_1, ..., b_P, T]``: the piece boundaries (breakpoints taken modulo ``T``, ``0`` always one)."""
    T = float(period)
    tol = 1e-12 * T
    points = sorted({float(b) % T for b in breakpoints})
    inner = [b for b in points if tol < b < T - tol]
    edges = [0.0]
    for b in inner:
        if b - edges[-1] > tol:
            edges.append(b)
    return np.array(edges + [T])


class PiecewiseGrid:
    """Gauss-Legendre nodes on the smooth pieces of ``[0, T)`` and the maps on them (see the module).

    Parameters
    ----------
    period : float
    breakpoints : sequence of float
        Times where the motion is not smooth (modulo ``T``); ``0`` is a piece boundary anyway.
    samples : int
        Total nodes ``K`` (at least :data:`MIN_NODES` per piece; shared in proportion to the lengths).

    Attributes
    ----------
    times : ndarray, shape (K,)
        The nodes, ascending.
    edges : ndarray, shape (P + 1,)
        Piece boundaries ``0 = e_0 < ... < e_P = T``.
    counts : tuple of int
        Nodes per piece.
    D1, D2 : ndarray, shape (K, K)
        First and second derivative at the nodes of the ``C^1`` piecewise interpolant.
    breakpoints : tuple of float
        The boundaries inside ``(0, T)``.
    boundaries : tuple of float
        ``(0,) + breakpoints``: what rebuilds the same grid (``PiecewiseGrid(T, boundaries, K)``), also
        for a single piece (no breakpoint inside the period).
    """

    def __init__(self, period: float, breakpoints: Sequence[float], samples: int) -> None:
        T = float(period)
        if not (math.isfinite(T) and T > 0):
            raise ValueError(f"period must be finite and > 0, got {period!r}")
        self.period = T
        self.edges = piece_edges(T, breakpoints)
        lengths = np.diff(self.edges)
        P = lengths.size
        K = int(samples)
        if K < MIN_NODES * P:
            raise ValueError(f"{K} samples cannot give {P} pieces {MIN_NODES} nodes each (at least "
                             f"{MIN_NODES * P} samples)")
        self.counts = _share(K, lengths)
        self.breakpoints = tuple(float(e) for e in self.edges[1:-1])
        self.boundaries = (0.0,) + self.breakpoints
        self._nodes = [legendre.leggauss(m)[0] for m in self.counts]  # on [-1, 1]
        self.times = np.concatenate([a + 0.5 * L * (x + 1.0) for a, L, x in zip(self.edges[:-1], lengths,
                                                                                 self._nodes)])
        self._coefficients = self._coefficient_map()
        self.D1 = self._derivative_at_nodes(1)
        self.D2 = self._derivative_at_nodes(2)
        # barycentric weights of each piece's nodes (Gauss-Legendre: (-1)^i sqrt((1 - x_i^2) w_i))
        self._weights = []
        for m in self.counts:
            x, w = legendre.leggauss(m)
            self._weights.append((-1.0) ** np.arange(m) * np.sqrt((1.0 - x**2) * w))

    # ------------------------------------------------------------------ construction
    def _coefficient_map(self) -> np.ndarray:
        """``(sum (m_j + 2), K)``: Legendre coefficients of the ``C^1`` periodic piecewise interpolant,
        piece after piece, from the node values."""
        lengths = np.diff(self.edges)
        P, K = lengths.size, int(sum(self.counts))
        sizes = [m + 2 for m in self.counts]
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        A = np.zeros((offsets[-1], offsets[-1]))
        row = 0
        for j, (m, x) in enumerate(zip(self.counts, self._nodes)):
            A[row:row + m, offsets[j]:offsets[j + 1]] = legendre.legvander(x, m + 1)
            row += m
        for j in range(P):  # end of piece j = start of piece j + 1 (cyclic): value and slope
            k = (j + 1) % P
            dj, dk = sizes[j] - 1, sizes[k] - 1
            end_v, start_v = _values_at(1.0, dj, 0), _values_at(-1.0, dk, 0)
            end_d = _values_at(1.0, dj, 1) * (2.0 / lengths[j])
            start_d = _values_at(-1.0, dk, 1) * (2.0 / lengths[k])
            A[row, offsets[j]:offsets[j + 1]] = end_v
            A[row, offsets[k]:offsets[k + 1]] -= start_v
            A[row + 1, offsets[j]:offsets[j + 1]] = end_d
            A[row + 1, offsets[k]:offsets[k + 1]] -= start_d
            row += 2
        rhs = np.zeros((offsets[-1], K))
        rhs[:K] = np.eye(K)
        return np.linalg.solve(A, rhs)

    def _derivative_at_nodes(self, order: int) -> np.ndarray:
        lengths = np.diff(self.edges)
        rows = []
        start = 0
        for m, x, L in zip(self.counts, self._nodes, lengths):
            block = self._coefficients[start:start + m + 2]
            rows.append(_vander_derivative(x, m + 1, order) * (2.0 / L) ** order @ block)
            start += m + 2
        return np.concatenate(rows)

    # ------------------------------------------------------------------ evaluation
    def _locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Piece index and local coordinate in ``[-1, 1]`` of each time (taken modulo ``T``)."""
        tt = np.mod(t, self.period)
        j = np.clip(np.searchsorted(self.edges, tt, side="right") - 1, 0, len(self.counts) - 1)
        a, L = self.edges[j], np.diff(self.edges)[j]
        return j, 2.0 * (tt - a) / L - 1.0

    def smooth(self, values: np.ndarray, times: np.ndarray | float, order: int = 0) -> np.ndarray:
        """The ``order``-th time derivative of the ``C^1`` piecewise interpolant of ``values``
        (node values along axis 0) at ``times`` -- the function the collocation solves for."""
        y = np.asarray(values, dtype=float)
        scalar = np.ndim(times) == 0
        t = np.atleast_1d(np.asarray(times, dtype=float))
        flat = y.reshape(y.shape[0], -1)
        coef = self._coefficients @ flat
        j, x = self._locate(t)
        out = np.empty((t.size, flat.shape[1]))
        lengths = np.diff(self.edges)
        start = 0
        for p, m in enumerate(self.counts):
            sel = j == p
            if sel.any():
                V = _vander_derivative(x[sel], m + 1, order) * (2.0 / lengths[p]) ** order
                out[sel] = V @ coef[start:start + m + 2]
            start += m + 2
        out = out.reshape((t.size,) + y.shape[1:])
        return out[0] if scalar else out

    def interpolate(self, values: np.ndarray, times: np.ndarray | float) -> np.ndarray:
        """Piece by piece, the polynomial of degree ``m_j - 1`` through the piece's node values
        (``values`` along axis 0), at ``times``; nothing continuous across the boundaries."""
        y = np.asarray(values, dtype=float)
        scalar = np.ndim(times) == 0
        t = np.atleast_1d(np.asarray(times, dtype=float))
        flat = y.reshape(y.shape[0], -1)
        j, x = self._locate(t)
        out = np.empty((t.size, flat.shape[1]))
        start = 0
        for p, m in enumerate(self.counts):
            sel = np.flatnonzero(j == p)
            if sel.size:
                out[sel] = _barycentric(self._nodes[p], self._weights[p], flat[start:start + m], x[sel])
            start += m
        out = out.reshape((t.size,) + y.shape[1:])
        return out[0] if scalar else out


def _share(K: int, lengths: np.ndarray) -> tuple:
    """``K`` nodes over the pieces in proportion to their lengths, at least :data:`MIN_NODES` each
    (largest remainders get the rest)."""
    P = lengths.size
    spare = K - MIN_NODES * P
    ideal = spare * lengths / lengths.sum()
    counts = np.floor(ideal).astype(int)
    order = np.argsort(-(ideal - counts), kind="stable")
    counts[order[:spare - int(counts.sum())]] += 1
    return tuple(int(c) + MIN_NODES for c in counts)


def _values_at(x: float, degree: int, order: int) -> np.ndarray:
    """Row of the ``order``-th derivatives of ``P_0 .. P_degree`` at the point ``x``."""
    return _vander_derivative(np.array([x]), degree, order)[0]


def _vander_derivative(x: np.ndarray, degree: int, order: int) -> np.ndarray:
    """``V[i, k] = d^order P_k / dx^order (x_i)``, ``k = 0..degree``."""
    V = np.empty((np.size(x), degree + 1))
    for k in range(degree + 1):
        c = np.zeros(degree + 1)
        c[k] = 1.0
        V[:, k] = legendre.legval(x, legendre.legder(c, order) if order else c)
    return V


def _barycentric(nodes: np.ndarray, weights: np.ndarray, values: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Second (true) barycentric formula; exact at the nodes."""
    diff = x[:, None] - nodes[None, :]
    exact = diff == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        c = weights[None, :] / diff
        out = (c @ values) / c.sum(axis=1)[:, None]
    hit = exact.any(axis=1)
    if hit.any():
        out[hit] = values[exact[hit].argmax(axis=1)]
    return out
