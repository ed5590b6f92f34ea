"""Central-difference Jacobians of a residual ``r(p, v, a, t)``.

The linearisation of ``r(p, p', p'', t) = 0`` about a motion ``p*(t)`` is
``M y'' + C y' + K y = 0`` with ``K = dr/dp``, ``C = dr/dp'`` and
``M = dr/dp''``.  For a residual written as ``M(p) p'' - f(p, p', t)`` this is
Exudyn's sign convention ``K = -df/dq``, ``C = -df/dq'`` plus the
derivative of the inertia terms along the motion.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["CENTRAL_DIFFERENCE_STEP", "central_difference_jacobians", "fd_steps"]

#: Relative step of the central differences: ``eps**(1/3)`` balances the
#: O(h^2) truncation error against the O(eps/h) rounding error.
CENTRAL_DIFFERENCE_STEP = float(np.finfo(float).eps ** (1.0 / 3.0))

Residual = Callable[[np.ndarray, np.ndarray, np.ndarray, float], np.ndarray]


def fd_steps(x: np.ndarray, step: float = CENTRAL_DIFFERENCE_STEP) -> np.ndarray:
    """Per-entry steps ``step * max(1, |x_i|)`` (coordinates are O(1) in SI units)."""
    x = np.asarray(x, dtype=float)
    return step * np.maximum(1.0, np.abs(x))


def central_difference_jacobians(
    residual: Residual,
    p: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
    t: float,
    *,
    step: float = CENTRAL_DIFFERENCE_STEP,
    columns: slice | np.ndarray | None = None,
    rows: slice | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``K = dr/dp`` and ``C = dr/dv`` by central differences.

    Parameters
    ----------
    residual : callable
        ``(p, v, a, t) -> r`` (1-D array).
    p, v, a : ndarray, shape (n,)
        The point of linearisation (coordinates, rates, accelerations).
    t : float
        Time.
    step : float
        Relative step (default :data:`CENTRAL_DIFFERENCE_STEP`); the
        absolute step of entry ``i`` is ``step * max(1, |x_i|)``.
    columns, rows : slice or index array, optional
        Differentiate only w.r.t. these entries / keep only these residual
        entries (default: all).

    Returns
    -------
    K, C : ndarray, shape (len(rows), len(columns))

    Notes
    -----
    Truncation error O(h^2): halving ``step`` divides the error by 4 (shown in
    ``tests/test_linearize.py``).
    """
    p = np.asarray(p, dtype=float)
    v = np.asarray(v, dtype=float)
    a = np.asarray(a, dtype=float)
    n = p.size
    cols = np.arange(n)[columns] if columns is not None else np.arange(n)
    rsel = rows if rows is not None else slice(None)
    r0 = np.asarray(residual(p, v, a, t))[rsel]
    K = np.empty((r0.size, cols.size))
    C = np.empty((r0.size, cols.size))
    hp = fd_steps(p, step)
    hv = fd_steps(v, step)
    for k, j in enumerate(cols):
        e = np.zeros(n)
        e[j] = hp[j]
        K[:, k] = (np.asarray(residual(p + e, v, a, t))[rsel] - np.asarray(residual(p - e, v, a, t))[rsel]) / (2 * hp[j])
        e[j] = hv[j]
        C[:, k] = (np.asarray(residual(p, v + e, a, t))[rsel] - np.asarray(residual(p, v - e, a, t))[rsel]) / (2 * hv[j])
    return K, C
