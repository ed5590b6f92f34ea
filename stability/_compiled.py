"""Compiled kernel (numba) for the batched Magnus-6 solves of small systems.

:func:`stability.floquet` solves a small system (``n <= SMALL_N``) at three step
counts in one batch.  On 4x4 matrices the numpy stacks of that batch
(:func:`stability.magnus.magnus_exponents_soa`, :func:`stability.expm.expm_soa`,
the level products) spend about as long in per-call overhead and temporaries
as in arithmetic; this kernel does the same steps in one compiled call, with
the loops over the stack innermost (contiguous, vectorised by LLVM):

* the Magnus-6 exponent of every sub-interval from ``P`` at its three Gauss
  nodes (Blanes, Casas, Oteo & Ros 2009, Eq. 257: the rows of
  ``stability.magnus._MAGNUS6_ROWS``), and its commutator part;
* the degree-16 Taylor exponential, Paterson-Stockmeyer, with scaling and
  squaring.  The scaling comes from ``alpha_3 = max(||A^3||^(1/3), ||A^4||^(1/4))``
  (Al-Mohy & Higham 2009, Thm 4.2) of the largest member *of each level*
  (the numpy path takes one scaling for the whole batch, that of the coarsest
  level; the finer levels here square fewer times: the same bound, less work);
* the ordered product ``E_N ... E_1`` of each level (sequential; the numpy path
  pairs: the same products in another rounding order).

Used when ``numba`` can be imported (it is a dependency of the package) and the
environment variable ``FLEXSTAB_NUMBA`` is not ``0``; otherwise, and for the
other schemes, the numpy path runs (same method, same accuracy; the test suite
checks both).  The machine code is compiled on first use (10-25 s) and cached on
disk by numba.
"""
from __future__ import annotations

import itertools
import logging
import math
import os
from typing import Any, Optional

import numpy as np

# the Taylor coefficients 1/k! and the largest alpha_3 at which the degree-16 polynomial is exact to
# double precision; the Magnus-6 constant sqrt(15)/3 (the same names as the numpy path)
from stability.expm import _TAYLOR, THETA_TAYLOR as _THETA
from stability.magnus import _K15

__all__ = ["available", "magnus6_levels"]

logger = logging.getLogger(__name__)


def _enabled() -> bool:
    return os.environ.get("FLEXSTAB_NUMBA", "1").strip().lower() not in ("0", "false", "no", "off")


try:  # this module is imported on the first small-system solve, not with the package
    if not _enabled():
        raise ImportError("disabled by FLEXSTAB_NUMBA")
    import numba
except ImportError as _exc:  # the numpy path
    numba = None
    logger.debug("compiled Magnus kernel unavailable: %s", _exc)


def _jit(func):
    """``numba.njit``, the machine code cached on disk (compiled lazily, on the first call); the
    plain function without numba."""
    if numba is None:
        return func
    try:
        return numba.njit(cache=True, boundscheck=False, error_model="numpy")(func)
    except RuntimeError:  # pragma: no cover - no writable cache directory: compiled in every process
        return numba.njit(cache=False, boundscheck=False, error_model="numpy")(func)


@_jit
def _mm(A, B, out, k0, k1):  # pragma: no cover - compiled by numba
    """``out[:, :, k] = A[:, :, k] @ B[:, :, k]`` for ``k0 <= k < k1`` (matrix-major stacks)."""
    n = A.shape[0]
    if n == 4:  # the reduced model: one pass over the stack per entry
        for i in range(4):
            for j in range(4):
                o = out[i, j, k0:k1]
                x0, x1, x2, x3 = A[i, 0, k0:k1], A[i, 1, k0:k1], A[i, 2, k0:k1], A[i, 3, k0:k1]
                y0, y1, y2, y3 = B[0, j, k0:k1], B[1, j, k0:k1], B[2, j, k0:k1], B[3, j, k0:k1]
                for k in range(k1 - k0):
                    o[k] = x0[k] * y0[k] + x1[k] * y1[k] + x2[k] * y2[k] + x3[k] * y3[k]
        return
    for i in range(n):
        for j in range(n):
            o = out[i, j, k0:k1]
            x = A[i, 0, k0:k1]
            y = B[0, j, k0:k1]
            for k in range(k1 - k0):
                o[k] = x[k] * y[k]
            for m in range(1, n):
                x = A[i, m, k0:k1]
                y = B[m, j, k0:k1]
                for k in range(k1 - k0):
                    o[k] += x[k] * y[k]


@_jit
def _comm(A, B, out, work):  # pragma: no cover - compiled by numba
    """``out = A B - B A`` over the whole stack (``work`` is overwritten)."""
    nt = A.shape[2]
    _mm(A, B, out, 0, nt)
    _mm(B, A, work, 0, nt)
    o = out.ravel()
    w = work.ravel()
    for k in range(o.size):
        o[k] -= w[k]


@_jit
def _column4(r0, r1, r2, r3, c0, c1, c2, c3):  # pragma: no cover - compiled by numba
    """The 4x4 matrix with rows ``r0 .. r3`` times the column ``(c0, c1, c2, c3)``, each entry summed
    left to right (``sum_m X[i, m] c_m``, ``m`` ascending)."""
    return (r0[0] * c0 + r0[1] * c1 + r0[2] * c2 + r0[3] * c3,
            r1[0] * c0 + r1[1] * c1 + r1[2] * c2 + r1[3] * c3,
            r2[0] * c0 + r2[1] * c1 + r2[2] * c2 + r2[3] * c3,
            r3[0] * c0 + r3[1] * c1 + r3[2] * c2 + r3[3] * c3)


@_jit
def _chain4(X, k0, k1, out):  # pragma: no cover - compiled by numba
    """``out = E_(k1-1) ... E_k0`` of the 4x4 stack ``X`` (matrix-major): the level product of
    :func:`_levels` with the running product in scalars (registers), the same arithmetic in the
    same order as its general loop (``sum_m X[i, m, k] phi[m, j]``, ``m`` ascending); each column
    of the product depends on the same column only."""
    a00, a01, a02, a03 = 1.0, 0.0, 0.0, 0.0
    a10, a11, a12, a13 = 0.0, 1.0, 0.0, 0.0
    a20, a21, a22, a23 = 0.0, 0.0, 1.0, 0.0
    a30, a31, a32, a33 = 0.0, 0.0, 0.0, 1.0
    for k in range(k0, k1):
        r0 = (X[0, 0, k], X[0, 1, k], X[0, 2, k], X[0, 3, k])
        r1 = (X[1, 0, k], X[1, 1, k], X[1, 2, k], X[1, 3, k])
        r2 = (X[2, 0, k], X[2, 1, k], X[2, 2, k], X[2, 3, k])
        r3 = (X[3, 0, k], X[3, 1, k], X[3, 2, k], X[3, 3, k])
        a00, a10, a20, a30 = _column4(r0, r1, r2, r3, a00, a10, a20, a30)
        a01, a11, a21, a31 = _column4(r0, r1, r2, r3, a01, a11, a21, a31)
        a02, a12, a22, a32 = _column4(r0, r1, r2, r3, a02, a12, a22, a32)
        a03, a13, a23, a33 = _column4(r0, r1, r2, r3, a03, a13, a23, a33)
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = a00, a01, a02, a03
    out[1, 0], out[1, 1], out[1, 2], out[1, 3] = a10, a11, a12, a13
    out[2, 0], out[2, 1], out[2, 2], out[2, 3] = a20, a21, a22, a23
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = a30, a31, a32, a33


@_jit
def _levels(P, ratio, hs, bounds, phis, stats):  # pragma: no cover - compiled by numba
    """The kernel (see the module notes).

    ``P`` ``(Ntot, 3, n, n)``, ``P`` at the Gauss nodes of every sub-interval, and ``ratio``
    ``(n, n)`` a factor on every entry (the balancing ``D^-1 P D``, ones without it), taken into
    the matrix-major stack ``Pg`` ``(3, n, n, Ntot)``; ``hs`` ``(Ntot,)`` the step lengths;
    ``bounds`` ``(L + 1,)`` the level boundaries along the stack.  Outputs: ``phis`` ``(L, n, n)``
    the level products; ``stats`` ``(L, 3)`` per level: ``sum_k tr Omega_k``, the largest column
    sum of ``|Omega_k - h Pbar_k|`` and of ``|Omega_k|`` (NaN propagates).
    """
    nt = P.shape[0]
    n = P.shape[2]
    mn = n * n
    Pg = np.empty((3, n, n, nt))
    for k in range(nt):
        for g in range(3):
            for i in range(n):
                for j in range(n):
                    Pg[g, i, j, k] = P[k, g, i, j] * ratio[i, j]
    a1 = np.empty((n, n, nt))
    a2 = np.empty((n, n, nt))
    a3 = np.empty((n, n, nt))
    c1 = np.empty((n, n, nt))
    w1 = np.empty((n, n, nt))
    w2 = np.empty((n, n, nt))
    om = np.empty((n, n, nt))
    p1f, p2f, p3f = Pg[0].reshape(mn, nt), Pg[1].reshape(mn, nt), Pg[2].reshape(mn, nt)
    a1f, a2f, a3f = a1.reshape(mn, nt), a2.reshape(mn, nt), a3.reshape(mn, nt)
    c1f, w2f, omf = c1.reshape(mn, nt), w2.reshape(mn, nt), om.reshape(mn, nt)
    # a1 = h A2, a2 = sqrt(15)/3 h (A3 - A1), 2 a3 = 20/3 h (A3 - 2 A2 + A1)
    for r in range(mn):
        p1, p2, p3 = p1f[r], p2f[r], p3f[r]
        x1, x2, x3 = a1f[r], a2f[r], a3f[r]
        for k in range(nt):
            h = hs[k]
            x1[k] = h * p2[k]
            x2[k] = _K15 * h * (p3[k] - p1[k])
            x3[k] = (20.0 / 3.0) * h * (p3[k] - 2.0 * p2[k] + p1[k])
    _comm(a1, a2, c1, w1)  # c1 = [a1, a2]
    for r in range(mn):
        x3, z = a3f[r], c1f[r]
        for k in range(nt):
            x3[k] += z[k]  # 2 a3 + c1
    _comm(a1, a3, w2, w1)  # [a1, 2 a3 + c1] = -60 c2
    for r in range(mn):
        p1, p2, p3 = p1f[r], p2f[r], p3f[r]
        x1, x2, y, z = a1f[r], a2f[r], w2f[r], c1f[r]
        for k in range(nt):
            h = hs[k]
            x1[k] = h * ((-10.0 / 3.0) * p1[k] - (40.0 / 3.0) * p2[k] - (10.0 / 3.0) * p3[k]) + z[k]
            x2[k] = h * (_K15 / 240.0) * (p3[k] - p1[k]) - y[k] / 14400.0
    _comm(a1, a2, c1, w1)  # C = (1/240) [-20 a1 - a3 + c1, a2 + c2]
    for r in range(mn):
        p1, p2, p3, o, z = p1f[r], p2f[r], p3f[r], omf[r], c1f[r]
        for k in range(nt):
            o[k] = hs[k] * (5.0 * p1[k] + 8.0 * p2[k] + 5.0 * p3[k]) / 18.0 + z[k]
    # powers (the work arrays reused): A2, A3, A4 of every exponent
    A2, A3, A4, X, Y = a1, a2, a3, w2, w1
    _mm(om, om, A2, 0, nt)
    _mm(A2, om, A3, 0, nt)
    _mm(A2, A2, A4, 0, nt)
    A2f, A3f, A4f, Xf, Yf = A2.reshape(mn, nt), A3.reshape(mn, nt), A4.reshape(mn, nt), X.reshape(mn, nt), Y.reshape(mn, nt)
    # largest column sums per member of |A^3|, |A^4|, |C|, |Omega|
    col = np.empty((4, nt))
    big = np.zeros((4, nt))
    for j in range(n):
        col[:, :] = 0.0
        for i in range(n):
            r = i * n + j
            for k in range(nt):
                col[0, k] += abs(A3f[r, k])
                col[1, k] += abs(A4f[r, k])
                col[2, k] += abs(c1f[r, k])
                col[3, k] += abs(omf[r, k])
        for d in range(4):
            for k in range(nt):
                v = col[d, k]
                if v > big[d, k] or v != v:  # a NaN stays (no later number replaces it)
                    big[d, k] = v
    cs = np.empty(17)
    tmp = np.empty((n, n))
    for lev in range(bounds.shape[0] - 1):
        k0, k1 = bounds[lev], bounds[lev + 1]
        top = np.zeros(4)  # the level's largest |A^3|, |A^4|, |C|, |Omega| column sums; a NaN stays
        trace = 0.0
        for k in range(k0, k1):
            for d in range(4):
                v = big[d, k]
                if v > top[d] or v != v:
                    top[d] = v
            for i in range(n):
                trace += omf[i * n + i, k]
        n3, n4, corr, size = top[0], top[1], top[2], top[3]
        stats[lev, 0] = trace
        stats[lev, 1] = corr
        stats[lev, 2] = size
        alpha = max(n3 ** (1.0 / 3.0), n4 ** 0.25)
        if not math.isfinite(alpha):
            phis[lev] = math.nan
            continue
        sq = 0
        if alpha > _THETA:
            sq = int(math.ceil(math.log2(alpha / _THETA)))
        f = 2.0 ** (-sq)
        if sq > 32:  # c_16 2^-16s would near the underflow threshold: scale the powers instead
            for r in range(mn):
                o, y2, y3, y4 = omf[r], A2f[r], A3f[r], A4f[r]
                for k in range(k0, k1):
                    o[k] *= f
                    y2[k] *= f * f
                    y3[k] *= f * f * f
                    y4[k] *= (f * f) * (f * f)
            f = 1.0
        for d in range(17):
            cs[d] = _TAYLOR[d] * f**d
        # Paterson-Stockmeyer: X = c16 A4 + B3, then X = A4 X + B_j, j = 2, 1, 0
        c12, c13, c14, c15, c16 = cs[12], cs[13], cs[14], cs[15], cs[16]
        for r in range(mn):
            x, o, y2, y3, y4 = Xf[r], omf[r], A2f[r], A3f[r], A4f[r]
            diag = c12 if r % (n + 1) == 0 else 0.0
            for k in range(k0, k1):
                x[k] = c16 * y4[k] + c13 * o[k] + c14 * y2[k] + c15 * y3[k] + diag
        for blk in range(2, -1, -1):
            _mm(A4, X, Y, k0, k1)
            e0, e1, e2, e3 = cs[4 * blk], cs[4 * blk + 1], cs[4 * blk + 2], cs[4 * blk + 3]
            for r in range(mn):
                x, y, o, y2, y3 = Xf[r], Yf[r], omf[r], A2f[r], A3f[r]
                diag = e0 if r % (n + 1) == 0 else 0.0
                for k in range(k0, k1):
                    x[k] = y[k] + e1 * o[k] + e2 * y2[k] + e3 * y3[k] + diag
        for _ in range(sq):
            _mm(X, X, Y, k0, k1)
            X, Y = Y, X  # the square is the new X (no copy)
            Xf, Yf = Yf, Xf
        phi = phis[lev]
        if n == 4:
            _chain4(X, k0, k1, phi)
            continue
        phi[:, :] = 0.0
        for i in range(n):
            phi[i, i] = 1.0
        for k in range(k0, k1):  # phi <- E_k phi
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for m in range(n):
                        s += X[i, m, k] * phi[m, j]
                    tmp[i, j] = s
            phi[:, :] = tmp


_state: dict[str, Any] = {}


def _kernel() -> Optional[Any]:
    """The compiled kernel, or None (numba missing or disabled, or the kernel failing to compile)."""
    if "kernel" not in _state:
        kernel = None
        if numba is not None:
            try:  # compile (or load from the cache) on a tiny problem, once per process
                _levels(np.zeros((1, 3, 1, 1)), np.ones((1, 1)), np.ones(1), np.array([0, 1], dtype=np.int64),
                        np.empty((1, 1, 1)), np.empty((1, 3)))
                kernel = _levels
            except Exception as exc:  # pragma: no cover - a broken numba installation
                logger.warning("compiled Magnus kernel failed to compile, using numpy: %s", exc)
        _state["kernel"] = kernel
    return _state["kernel"]


def available() -> bool:
    """Whether the compiled kernel runs (compiles it on first call)."""
    return _kernel() is not None


def magnus6_levels(P: np.ndarray, h: np.ndarray, Ns: list[int],
                   ratio: Optional[np.ndarray] = None) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """Magnus-6 level products of a batch of sub-intervals by the compiled kernel.

    Parameters
    ----------
    P : ndarray, shape (sum(Ns), 3, n, n)
        ``P`` at the three Gauss nodes of every sub-interval (as ``evaluate`` returns it for the
        nodes in time order), the levels one after another.
    h : ndarray, shape (sum(Ns),)
        Step length of every sub-interval.
    Ns : list of int
        Sub-intervals of each level.
    ratio : ndarray, shape (n, n), optional
        Factor on every entry of ``P`` (the balancing ``D^-1 P D`` as ``d_j / d_i``); none by default.

    Returns
    -------
    (phis, stats) or None
        ``phis`` ``(L, n, n)`` the products ``E_N ... E_1`` of each level; ``stats`` ``(L, 3)``:
        ``sum_k tr Omega_k``, ``max_k ||Omega_k - h Pbar_k||_1``, ``max_k ||Omega_k||_1``.
        None when the kernel is not available.
    """
    kernel = _kernel()
    if kernel is None:
        return None
    n = P.shape[-1]
    bounds = np.array([0, *itertools.accumulate(Ns)], dtype=np.int64)  # (np.cumsum costs more on a short list)
    phis = np.empty((len(Ns), n, n))
    stats = np.empty((len(Ns), 3))
    ratio = np.ones((n, n)) if ratio is None else ratio
    kernel(_writable(P), _writable(ratio), _writable(h), bounds, phis, stats)
    return phis, stats


def _writable(a: np.ndarray) -> np.ndarray:
    """``a`` as a writable C-contiguous float64 array, the only kind the kernel is compiled for (a
    read-only one, such as the cached step lengths, is another numba type: a second compilation);
    ``a`` itself when it is one already (``np.require``'s checks cost more than these)."""
    if a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.require(a, np.float64, ["C", "W"])
