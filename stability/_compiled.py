"""Optional compiled kernel (numba) for the Magnus solves of small systems.

The fused loop does per sub-interval what :func:`stability.magnus.magnus_exponents_soa`,
:func:`stability.expm.expm_soa` and :func:`stability.magnus.ordered_product_soa`
do on whole stacks: the Magnus-4/6 exponent from ``P`` at the Gauss points,
its commutator part (the :data:`stability.floquet.COMMUTATOR_LIMIT` test), the
degree-16 Taylor exponential with scaling and squaring (scaling from
``alpha_3 = max(||A^3||^(1/3), ||A^4||^(1/4))``, Al-Mohy & Higham 2009, here
per matrix rather than once per stack) and the ordered product
``E_N ... E_1`` (sequential instead of pairwise: the same products, another
rounding order).  For 4x4 matrices the numpy stacks spend most of their time in
per-call overhead and temporaries; the fused loop runs at the arithmetic.

Optional: install ``numba`` (``pip install flexstab[fast]``).  Without it, or
with the environment variable ``FLEXSTAB_NUMBA=0``, :data:`AVAILABLE` is
``False`` and the numpy path runs (same algorithm, same accuracy).
"""
from __future__ import annotations

import math
import os

import numpy as np

__all__ = ["AVAILABLE", "magnus_solve"]

try:  # pragma: no cover - depends on the environment
    if os.environ.get("FLEXSTAB_NUMBA", "1").strip() in ("0", "false", "no", "off"):
        raise ImportError("disabled by FLEXSTAB_NUMBA")
    import numba

    AVAILABLE = True
except ImportError:  # pragma: no cover - depends on the environment
    numba = None
    AVAILABLE = False

#: Taylor coefficients 1/k!, k = 0..16, and the largest 1-norm at which the
#: degree-16 polynomial is exact to double precision (see stability.expm).
_TAYLOR = np.array([1.0 / math.factorial(k) for k in range(17)])
_THETA = 0.82
_S15 = math.sqrt(15.0)
_S3 = math.sqrt(3.0)


def _magnus_solve_py(P, h, order, phi, stats):  # pragma: no cover - compiled by numba
    """Fused Magnus solve over ``N`` sub-intervals.

    Parameters
    ----------
    P : ndarray, shape (N, q, n, n)
        ``P`` at the ``q`` Gauss nodes of each sub-interval (time order).
    h : float
    order : int
        4 or 6.
    phi : ndarray, shape (n, n)
        Output: ``E_N ... E_1``.
    stats : ndarray, shape (3,)
        Output: ``sum_k tr Omega_k``, the largest 1-norm of the commutator part
        ``Omega_k - h Pbar_k`` and the largest 1-norm of ``Omega_k``.
    """
    N = P.shape[0]
    n = P.shape[2]
    c = _TAYLOR
    a1 = np.empty((n, n))
    a2 = np.empty((n, n))
    a3 = np.empty((n, n))
    t1 = np.empty((n, n))
    t2 = np.empty((n, n))
    c1 = np.empty((n, n))
    om = np.empty((n, n))
    A2 = np.empty((n, n))
    A3 = np.empty((n, n))
    A4 = np.empty((n, n))
    X = np.empty((n, n))
    Y = np.empty((n, n))
    tmp = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            phi[i, j] = 1.0 if i == j else 0.0
    logdet = 0.0
    corr_max = 0.0
    om_max = 0.0
    for k in range(N):
        # ---- exponent Omega_k (Blanes et al. 2009, Eqs. 253 / 257) and its commutator part
        if order == 6:
            for i in range(n):
                for j in range(n):
                    p1 = P[k, 0, i, j]
                    p2 = P[k, 1, i, j]
                    p3 = P[k, 2, i, j]
                    a1[i, j] = h * p2
                    a2[i, j] = (_S15 / 3.0) * h * (p3 - p1)
                    a3[i, j] = (10.0 / 3.0) * h * (p3 - 2.0 * p2 + p1)
            # c1 = [a1, a2]
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for m in range(n):
                        s += a1[i, m] * a2[m, j] - a2[i, m] * a1[m, j]
                    c1[i, j] = s
            # t1 = 2 a3 + c1 ; c2 = -1/60 [a1, t1] (stored in t2)
            for i in range(n):
                for j in range(n):
                    t1[i, j] = 2.0 * a3[i, j] + c1[i, j]
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for m in range(n):
                        s += a1[i, m] * t1[m, j] - t1[i, m] * a1[m, j]
                    t2[i, j] = -s / 60.0
            # om = a1 + a3/12 + 1/240 [-20 a1 - a3 + c1, a2 + c2]
            for i in range(n):
                for j in range(n):
                    t1[i, j] = -20.0 * a1[i, j] - a3[i, j] + c1[i, j]
                    t2[i, j] = a2[i, j] + t2[i, j]
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for m in range(n):
                        s += t1[i, m] * t2[m, j] - t2[i, m] * t1[m, j]
                    om[i, j] = a1[i, j] + a3[i, j] / 12.0 + s / 240.0
            for j in range(n):
                s = 0.0
                for i in range(n):
                    mean = (5.0 * P[k, 0, i, j] + 8.0 * P[k, 1, i, j] + 5.0 * P[k, 2, i, j]) / 18.0
                    s += abs(om[i, j] - h * mean)
                if not s <= corr_max:  # NaN propagates
                    corr_max = s
        else:
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for m in range(n):
                        s += P[k, 1, i, m] * P[k, 0, m, j] - P[k, 0, i, m] * P[k, 1, m, j]
                    om[i, j] = 0.5 * h * (P[k, 0, i, j] + P[k, 1, i, j]) + (_S3 / 12.0) * h * h * s
            for j in range(n):
                s = 0.0
                for i in range(n):
                    s += abs(om[i, j] - 0.5 * h * (P[k, 0, i, j] + P[k, 1, i, j]))
                if not s <= corr_max:
                    corr_max = s
        for i in range(n):
            logdet += om[i, i]
        for j in range(n):
            s = 0.0
            for i in range(n):
                s += abs(om[i, j])
            if not s <= om_max:
                om_max = s
        # ---- exp(Omega_k): degree-16 Taylor, Paterson-Stockmeyer, scaling and squaring
        for i in range(n):
            for j in range(n):
                s2 = 0.0
                for m in range(n):
                    s2 += om[i, m] * om[m, j]
                A2[i, j] = s2
        for i in range(n):
            for j in range(n):
                s3 = 0.0
                s4 = 0.0
                for m in range(n):
                    s3 += A2[i, m] * om[m, j]
                    s4 += A2[i, m] * A2[m, j]
                A3[i, j] = s3
                A4[i, j] = s4
        n3 = 0.0
        n4 = 0.0
        for j in range(n):
            s3 = 0.0
            s4 = 0.0
            for i in range(n):
                s3 += abs(A3[i, j])
                s4 += abs(A4[i, j])
            n3 = max(n3, s3)
            n4 = max(n4, s4)
        alpha = max(n3 ** (1.0 / 3.0), n4 ** 0.25)
        if not math.isfinite(alpha):
            for i in range(n):
                for j in range(n):
                    phi[i, j] = math.nan
            stats[0] = logdet
            stats[1] = math.inf
            stats[2] = math.inf
            return
        sq = 0
        if alpha > _THETA:
            sq = int(math.ceil(math.log2(alpha / _THETA)))
        if sq > 0:
            f = 2.0 ** (-sq)
            f2 = f * f
            for i in range(n):
                for j in range(n):
                    om[i, j] *= f
                    A2[i, j] *= f2
                    A3[i, j] *= f2 * f
                    A4[i, j] *= f2 * f2
        # X = c16 A4 + B3, then X = A4 X + B_j for j = 2, 1, 0
        for i in range(n):
            for j in range(n):
                X[i, j] = c[16] * A4[i, j] + c[13] * om[i, j] + c[14] * A2[i, j] + c[15] * A3[i, j]
            X[i, i] += c[12]
        for blk in range(2, -1, -1):
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for m in range(n):
                        s += A4[i, m] * X[m, j]
                    Y[i, j] = s + c[4 * blk + 1] * om[i, j] + c[4 * blk + 2] * A2[i, j] + c[4 * blk + 3] * A3[i, j]
                Y[i, i] += c[4 * blk]
            for i in range(n):
                for j in range(n):
                    X[i, j] = Y[i, j]
        for _ in range(sq):
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for m in range(n):
                        s += X[i, m] * X[m, j]
                    Y[i, j] = s
            for i in range(n):
                for j in range(n):
                    X[i, j] = Y[i, j]
        # ---- phi <- E_k phi
        for i in range(n):
            for j in range(n):
                s = 0.0
                for m in range(n):
                    s += X[i, m] * phi[m, j]
                tmp[i, j] = s
        for i in range(n):
            for j in range(n):
                phi[i, j] = tmp[i, j]
    stats[0] = logdet
    stats[1] = corr_max
    stats[2] = om_max


def _jit(func):
    """``numba.njit`` with the machine code cached on disk (compiling the unrolled 4x4 kernel takes
    ~15 s once); without caching where no cache directory is writable."""
    try:
        return numba.njit(cache=True, nogil=True)(func)
    except RuntimeError:  # pragma: no cover - read-only installation without a user cache dir
        return numba.njit(cache=False, nogil=True)(func)


if AVAILABLE:  # pragma: no branch
    from stability._kernel4 import magnus_solve_4 as _solve4_py

    _kernel = _jit(_magnus_solve_py)
    #: the same loop unrolled for 4x4 (the reduced model), generated by stability._codegen
    _kernel4 = _jit(_solve4_py)
else:
    _kernel = _kernel4 = None


def magnus_solve(P: np.ndarray, h: float, order: int) -> tuple[np.ndarray, float, float, float]:
    """``(Phi, sum tr Omega_k, max ||Omega_k - h Pbar_k||_1, max ||Omega_k||_1)`` by the compiled kernel.

    ``P`` has shape ``(N, q, n, n)`` (``q = 2`` for ``order = 4``, 3 for 6).
    Only when :data:`AVAILABLE`.
    """
    if _kernel is None:
        raise RuntimeError("the compiled kernel needs numba (pip install flexstab[fast])")
    n = P.shape[-1]
    phi = np.empty((n, n))
    stats = np.empty(3)
    kernel = _kernel4 if n == 4 else _kernel
    kernel(np.ascontiguousarray(P, dtype=np.float64), float(h), int(order), phi, stats)
    return phi, float(stats[0]), float(stats[1]), float(stats[2])
