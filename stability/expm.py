"""Matrix exponential of a stack of matrices, vectorised over the stack.

``scipy.linalg.expm`` accepts stacks but loops over them in Python-level
calls (about 0.25 ms per 4x4 matrix when scaling is needed), which dominates
a Magnus step.  Here the same algorithm -- scaling and squaring with the
Pade approximant of degree 3, 5, 7, 9 or 13 chosen from the 1-norm (Higham
2005, Algorithm 2.3) -- runs on the whole stack at once with batched
``matmul`` and ``solve``.  One degree and one scaling serve the whole stack
(those of its largest norm): over-scaling the smaller members costs nothing in
accuracy at these norms and avoids masked (gather/scatter) squarings.

References
----------
.. [1] Higham, N. J., "The scaling and squaring method for the matrix
       exponential revisited", SIAM J. Matrix Anal. Appl. 26 (2005) 1179-1193.
.. [2] Al-Mohy, A. H., Higham, N. J., "A new scaling and squaring algorithm for
       the matrix exponential", SIAM J. Matrix Anal. Appl. 31 (2009) 970-989
       (``scipy.linalg.expm``, used for matrices larger than ``SCIPY_N``).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["expm_stack", "expm_soa", "mm_soa"]

#: Pade coefficients b_0..b_m (Higham 2005, Alg. 2.3).
_B = {
    3: (120.0, 60.0, 12.0, 1.0),
    5: (30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0),
    7: (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0),
    9: (17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0,
        2162160.0, 110880.0, 3960.0, 90.0, 1.0),
    13: (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
         129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0,
         1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0),
}
#: Largest 1-norm for which the [m/m] approximant reaches double precision
#: without scaling (Higham 2005, Table 2.3: theta_m).
THETA = {3: 1.495585217958292e-2, 5: 2.539398330063230e-1, 7: 9.504178996162932e-1,
         9: 2.097847961257068, 13: 5.371920351148152}
THETA_13 = THETA[13]
#: Matrices larger than this go to ``scipy.linalg.expm`` (Al-Mohy & Higham 2009).
SCIPY_N = 16


def expm_stack(A: np.ndarray) -> np.ndarray:
    """``expm`` of every matrix in a stack.

    Parameters
    ----------
    A : ndarray, shape (N, n, n)

    Returns
    -------
    ndarray, shape (N, n, n)
    """
    A = np.asarray(A, dtype=float)
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise ValueError(f"expected a stack of square matrices (N, n, n), got {A.shape}")
    n = A.shape[-1]
    if A.shape[0] == 0:
        return A.copy()
    if n > SCIPY_N:
        # large matrices: the per-matrix Python loop of scipy costs nothing against the
        # arithmetic, and its scaling from ||A^k||^(1/k) (Al-Mohy & Higham 2009) needs
        # far fewer squarings for the non-normal matrices of a linearised FE model
        # (8 elements: ||h P||_1 = 2e5 but ||(h P)^8||^(1/8) = 3e3)
        from scipy.linalg import expm as scipy_expm

        return np.asarray(scipy_expm(A), dtype=float)
    norm = float(np.max(np.sum(np.abs(A), axis=1)))  # largest 1-norm in the stack
    if not math.isfinite(norm):
        return np.full_like(A, np.nan)
    ident = np.eye(n)
    for m in (3, 5, 7, 9):
        if norm <= THETA[m]:
            b = _B[m]
            A2 = A @ A
            if m == 3:
                U = A @ (b[3] * A2 + b[1] * ident)
                V = b[2] * A2 + b[0] * ident
            elif m == 5:
                A4 = A2 @ A2
                U = A @ (b[5] * A4 + b[3] * A2 + b[1] * ident)
                V = b[4] * A4 + b[2] * A2 + b[0] * ident
            elif m == 7:
                A4 = A2 @ A2
                A6 = A4 @ A2
                U = A @ (b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * ident)
                V = b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * ident
            else:
                A4 = A2 @ A2
                A6 = A4 @ A2
                A8 = A6 @ A2
                U = A @ (b[9] * A8 + b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * ident)
                V = b[8] * A8 + b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * ident
            return np.linalg.solve(V - U, V + U)
    s = max(0, int(math.ceil(math.log2(norm / THETA_13))))
    As = A * (2.0**-s)
    b = _B[13]
    A2 = As @ As
    A4 = A2 @ A2
    A6 = A4 @ A2
    U = As @ (A6 @ (b[13] * A6 + b[11] * A4 + b[9] * A2) + b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * ident)
    V = A6 @ (b[12] * A6 + b[10] * A4 + b[8] * A2) + b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * ident
    X = np.linalg.solve(V - U, V + U)
    for _ in range(s):
        X = X @ X
    return X


# --------------------------------------------------------------------------- small matrices
#: Degree of the Taylor polynomial of :func:`expm_soa`.
TAYLOR_DEGREE = 16
#: Largest 1-norm for which the degree-16 Taylor polynomial is exact to double
#: precision: the remainder is ``<= theta^17 / 17! / (1 - theta / 18)``, which is
#: the unit roundoff 1.1e-16 at ``theta = (1.1e-16 * 17!)^(1/17) = 0.826``.
THETA_TAYLOR = 0.82
_TAYLOR = np.array([1.0 / math.factorial(k) for k in range(TAYLOR_DEGREE + 1)])
#: Coefficients of the four degree-3 blocks of the Paterson-Stockmeyer scheme,
#: ``B_j = sum_i c_{4j+i} A^i`` (rows j = 0..3, columns i = 0..3).
_PS_BLOCKS = _TAYLOR[:16].reshape(4, 4)


try:  # numpy's C einsum without the Python argument handling (same function np.einsum calls)
    from numpy._core._multiarray_umath import c_einsum as _c_einsum
except ImportError:  # pragma: no cover - other numpy layouts
    _c_einsum = np.einsum


def mm_soa(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A_k @ B_k`` for stacks stored *matrix-major*, shape ``(n, n, N)`` (the stack index last).

    For small ``n`` (4x4 in the reduced model) this layout lets the inner loop
    run over the stack, contiguous, instead of one tiny BLAS call per matrix.
    """
    return _c_einsum("ijk,jlk->ilk", A, B)


def expm_soa(A: np.ndarray) -> np.ndarray:
    """``expm`` of every matrix of a matrix-major stack ``(n, n, N)`` (small ``n``).

    Scaling and squaring with the degree-16 Taylor polynomial, evaluated by
    Paterson-Stockmeyer (``A^2, A^3, A^4`` and four Horner steps in ``A^4``:
    7 products, no linear solve).  One scaling for the whole stack, from
    ``alpha_3 = max(||A^3||^(1/3), ||A^4||^(1/4))`` of its largest member (no
    larger than the 1-norm, and much smaller for non-normal matrices).

    References
    ----------
    .. [1] Paterson, M. S., Stockmeyer, L. J., "On the number of nonscalar
           multiplications necessary to evaluate polynomials", SIAM J. Comput.
           2 (1973) 60-66.
    .. [2] Moler, C., Van Loan, C., "Nineteen dubious ways to compute the
           exponential of a matrix, twenty-five years later", SIAM Rev. 45
           (2003) 3-49 (Taylor with scaling and squaring).
    .. [3] Al-Mohy, A. H., Higham, N. J., SIAM J. Matrix Anal. Appl. 31 (2009)
           970-989, Theorem 4.2 (scaling from ``||A^k||^(1/k)``).
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    if A.size == 0:
        return A.copy()
    A2 = mm_soa(A, A)
    A3 = mm_soa(A2, A)
    A4 = mm_soa(A2, A2)
    # scaling from alpha_3 = max(||A^3||^(1/3), ||A^4||^(1/4)) <= ||A|| (Al-Mohy & Higham 2009,
    # Thm 4.2 with p = 3, p (p - 1) <= 17: the Taylor remainder, a series with positive
    # coefficients, is bounded by the same series in alpha_3)
    with np.errstate(over="ignore", invalid="ignore"):
        d3 = float(np.abs(A3).sum(axis=0).max()) ** (1.0 / 3.0)
        d4 = float(np.abs(A4).sum(axis=0).max()) ** 0.25
    alpha = max(d3, d4)
    if not math.isfinite(alpha):
        return np.full_like(A, np.nan)
    s = max(0, int(math.ceil(math.log2(alpha / THETA_TAYLOR)))) if alpha > 0 else 0
    if s:
        f = 2.0**-s
        A, A2, A3, A4 = A * f, A2 * f**2, A3 * f**3, A4 * f**4
    diag = np.arange(n)
    c = _PS_BLOCKS

    def block(j: int, X: np.ndarray) -> np.ndarray:
        """``B_j + X`` with ``B_j = c_{4j} I + c_{4j+1} A + c_{4j+2} A^2 + c_{4j+3} A^3``."""
        X += c[j, 1] * A
        X += c[j, 2] * A2
        X += c[j, 3] * A3
        X[diag, diag] += c[j, 0]
        return X

    X = block(3, _TAYLOR[16] * A4)
    X = block(2, mm_soa(A4, X))
    X = block(1, mm_soa(A4, X))
    X = block(0, mm_soa(A4, X))
    for _ in range(s):
        X = mm_soa(X, X)
    return X
