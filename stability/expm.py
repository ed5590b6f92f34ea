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

import functools
import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

__all__ = ["expm_stack", "expm_soa", "mm_soa", "expm_near_block_diagonal", "BlockExpm"]

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


@functools.lru_cache(maxsize=64)
def _taylor_blocks(s: int) -> tuple[np.ndarray, float]:
    """The Paterson-Stockmeyer coefficients of :func:`expm_soa` with the scaling ``2^-s`` folded in:
    ``c_k 2^-ks`` as the ``(4, 4)`` blocks and ``c_16 2^-16s`` (cached: a handful of ``s`` occur;
    read-only)."""
    f = 2.0**-s
    c = _PS_BLOCKS * (f ** np.arange(TAYLOR_DEGREE)).reshape(4, 4)
    c.flags.writeable = False
    return c, float(_TAYLOR[16] * f**16)


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
    # A, A^2, A^3 in one contiguous array: the four Taylor blocks below are one product with it
    powers = np.empty((3,) + A.shape)
    powers[0] = A
    A2 = _c_einsum("ijk,jlk->ilk", A, A, out=powers[1])
    A3 = _c_einsum("ijk,jlk->ilk", A2, A, out=powers[2])
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
    # the scaling 2^-s is folded into the coefficients, c_k 2^-ks A^k = c_k (2^-s A)^k: powers of two
    # scale exactly, so this equals scaling the powers (bit for bit away from under/overflow)
    if s > 32:  # c_16 2^-16s would approach the underflow threshold: scale the powers instead
        f = 2.0**-s
        powers[0] *= f
        powers[1] *= f**2
        powers[2] *= f**3
        A4 = A4 * f**4
        c, c16 = _taylor_blocks(0)
    else:
        c, c16 = _taylor_blocks(s)
    # the four degree-3 blocks B_j = sum_{i>=1} c_{4j+i} A^i in one product (4 x 3) @ (3 x n n N)
    B = (c[:, 1:] @ powers.reshape(3, -1)).reshape((4,) + A.shape)
    # + c_{4j} I: the diagonal of each block as a strided view of its (n n, N) rows
    B.reshape(4, n * n, -1)[:, :: n + 1] += c[:, :1, None]
    X = c16 * A4
    X += B[3]
    X = mm_soa(A4, X)
    X += B[2]
    X = mm_soa(A4, X)
    X += B[1]
    X = mm_soa(A4, X)
    X += B[0]
    for _ in range(s):
        X = mm_soa(X, X)
    return X


# --------------------------------------------------------------------------- nearly block-diagonal matrices
#: Relative residual ``||A~ Z - Z D'||_1 / (||A~||_1 ||Z||_1)`` at which the block
#: diagonalisation of :func:`expm_near_block_diagonal` stops (4.5 unit roundoffs:
#: the rounding floor of forming ``A Z`` is ``n u`` in the worst case, about ``u`` in practice).
BLOCK_RESIDUAL_TOL = 1e-15
#: At most this many refinement sweeps (each one ``n x n`` GEMM); more means the
#: coupling is too strong for the method to pay and it falls back.
BLOCK_MAX_SWEEPS = 8
#: Largest accepted ``cond_1(Z)`` (LAPACK ``dgecon`` estimate) and ``cond_1(W_a)``
#: of a diagonal block's eigenvectors; beyond, the forward error bound
#: ``~ u cond(Z)^2 ...`` is no longer at the level of ``scipy.linalg.expm`` and it falls back.
BLOCK_COND_LIMIT = 10.0
BLOCK_EIG_COND_LIMIT = 1e3
#: Largest accepted 1-norm of one correction ``||Y||_1`` (the first one is the
#: coupling over the gaps, ``~ max |F_ab| / |lambda_a - lambda_b|``).
BLOCK_COUPLING_LIMIT = 0.25


@dataclass(frozen=True)
class BlockExpm:
    """Result of :func:`expm_near_block_diagonal`.

    Attributes
    ----------
    matrix : ndarray or None
        ``expm(A)``; ``None`` when the method refused (``reason`` says why).
    sweeps : int
        Refinement sweeps done (one ``n x n`` GEMM each).
    residual : float
        Relative residual ``||A~ Z - Z D'||_1 / (||A~||_1 ||Z||_1)`` reached (computed, or its
        GEMM-free bound when that stopped the refinement)
        (``A~ = T^-1 A T``, see :func:`expm_near_block_diagonal`).
    condition : float
        ``cond_1(Z)`` estimate (LAPACK ``dgecon``); NaN if not reached.
    error_bound : float
        First-order bound on ``||matrix - expm(A)||_1`` (see the function notes).
    reason : str
        Empty on success, else why it refused.
    """

    matrix: Optional[np.ndarray]
    sweeps: int
    residual: float
    condition: float
    error_bound: float
    reason: str

    @property
    def ok(self) -> bool:
        return self.matrix is not None


def _refuse(reason: str, sweeps: int = 0, residual: float = math.nan, cond: float = math.nan) -> BlockExpm:
    return BlockExpm(None, sweeps, residual, cond, math.nan, reason)


def _inv22(T: np.ndarray) -> np.ndarray:
    """Inverses of a stack of 2x2 matrices (closed form)."""
    det = T[:, 0, 0] * T[:, 1, 1] - T[:, 0, 1] * T[:, 1, 0]
    out = np.empty_like(T)
    out[:, 0, 0], out[:, 1, 1] = T[:, 1, 1] / det, T[:, 0, 0] / det
    out[:, 0, 1], out[:, 1, 0] = -T[:, 0, 1] / det, -T[:, 1, 0] / det
    return out


def _left_planar(T: np.ndarray, R: np.ndarray, o: int) -> None:
    """``R <- blockdiag(T) R`` in place for the 2x2 blocks ``T`` (m, 2, 2) acting on the row
    pairs ``(o + i, o + m + i)`` (planar layout: first components, then second components)."""
    m = T.shape[0]
    if m == 0:
        return
    a, b = R[o:o + m], R[o + m:o + 2 * m]
    na = T[:, 0, 0, None] * a + T[:, 0, 1, None] * b
    b *= T[:, 1, 1, None]
    b += T[:, 1, 0, None] * a
    a[...] = na


def _right_planar(R: np.ndarray, T: np.ndarray, o: int) -> None:
    """``R <- R blockdiag(T)`` in place on the column pairs ``(o + i, o + m + i)``."""
    m = T.shape[0]
    if m == 0:
        return
    a, b = R[:, o:o + m], R[:, o + m:o + 2 * m]
    na = a * T[None, :, 0, 0] + b * T[None, :, 1, 0]
    b *= T[None, :, 1, 1]
    b += a * T[None, :, 0, 1]
    a[...] = na


def expm_near_block_diagonal(A: np.ndarray, blocks: Sequence[int], *,
                             max_sweeps: int = BLOCK_MAX_SWEEPS) -> BlockExpm:
    """``expm(A)`` of a real matrix that is nearly block diagonal, by block diagonalisation.

    ``A = D + F``, ``D`` the contiguous diagonal blocks of sizes ``blocks`` (1 or 2)
    and ``F`` small against the gaps between the eigenvalues of different blocks.

    Basis: each 2x2 block with eigenvalues ``alpha +- i beta`` is brought to the real normal
    form ``S = [[alpha, beta], [-beta, alpha]]`` by ``T_a = [Re w, Im w]`` (``w`` its
    eigenvector, phase chosen so that ``Re w`` is orthogonal to ``Im w``); one with two real
    eigenvalues is diagonalised (two 1x1 blocks).  In that basis ``A~ = T^-1 A T``
    (``T`` block diagonal) refine ``Z = I + X`` (``X`` zero on the diagonal blocks)
    until ``A~ Z = Z D'``, ``D'`` block diagonal: each sweep forms the residual
    ``R = A~ Z - Z D'`` (one ``n x n`` GEMM, the only ``O(n^3)`` work of a sweep),
    puts its diagonal blocks into ``D'`` and removes its off-diagonal blocks by the
    Sylvester equations ``S_a Y_ab - Y_ab S_b = -R_ab`` (``S``: the blocks of ``A~``),
    solved entrywise: for two normal forms ``Y = Y+ + Y-`` with ``Y+`` commuting and
    ``Y-`` anticommuting with ``J = [[0, 1], [-1, 0]]``, each a complex number
    divided by ``(alpha_a - alpha_b) + i (beta_a - beta_b)`` resp.
    ``(alpha_a - alpha_b) - i (beta_a + beta_b)``; ``X += Y``.  The Jacobian is taken at
    ``Z = I``, ``D' = S``, so each sweep reduces the residual by a factor
    ``~ ||X|| + ||D' - S|| / gap`` (the coupling over the gaps: a linear rate, no GEMM for
    the update).  After each update the new residual is first bounded without a GEMM:
    ``R + S Y - Y S = 0`` gives ``R' = F Y - Y (D'' - S) - Z (D'' - D')`` (``F = A~ - S``,
    ``D''`` the diagonal blocks of ``A~ (Z + Y)``, ``O(n^2)``), so
    ``||R'|| <= ||F|| ||Y|| + ||Y|| ||D'' - S|| + ||Z|| ||D'' - D'||``; the refinement stops
    when that bound (or the residual of a GEMM sweep) is below :data:`BLOCK_RESIDUAL_TOL`
    (the single link's frames at 64 elements: 2 GEMMs).  Then ``expm(A) = T Z expm(D') Z^-1 T^-1``: the small blocks'
    exponentials (:func:`expm_stack`), one LU of ``Z`` and one solve.

    Error: with the residual ``R``, ``A~ - R Z^-1 = Z D' Z^-1`` exactly, so the
    result is ``expm`` of ``A~`` perturbed by ``dA = R Z^-1`` (``||R||`` the computed
    residual plus the rounding of computing it, ``n u ||A~|| ||Z||``: backward stable at the
    level of ``scipy.linalg.expm``, whose backward error is ``~ u ||A||`` by design plus the
    rounding of its products), plus the rounding of
    ``Z expm(D') Z^-1`` (``~ n u cond(Z) ||expm(D')||``).  With ``expm(A~ s) = Z expm(D' s) Z^-1``
    and ``expm(A~) - expm(A~ - dA) = int_0^1 expm(A~ s) dA expm((A~ - dA)(1 - s)) ds``,
    ``||expm(A~) - expm(A~ - dA)|| <= ||dA|| cond(Z)^2 M^2``, ``M = max_{0<=s<=1} ||expm(D' s)||``;
    ``T`` maps it back with ``cond(T)``, so
    ``error_bound = cond(T) (cond(Z)^2 M^2 (rho + n u) ||A~|| ||Z|| ||Z^-1|| + n u cond(Z) M)``
    (``rho`` the relative residual reached; 1-norms,
    first order; ``M`` taken as ``max(1, ||expm(D')||_1)``, exact for blocks whose norm does
    not grow, as for the damped or undamped modes of a frozen-modal frame).

    Refuses (``matrix=None``, ``reason`` set; the caller falls back to
    ``scipy.linalg.expm``) for blocks larger than 2x2, a nearly defective block
    (``cond(T_a) >`` :data:`BLOCK_EIG_COND_LIMIT`), two blocks sharing an eigenvalue,
    a large correction (``||Y||_1 >`` :data:`BLOCK_COUPLING_LIMIT`: clusters too close),
    a residual that stalls or needs more than ``max_sweeps`` sweeps, or
    ``cond(Z) >`` :data:`BLOCK_COND_LIMIT`.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    blocks : sequence of int
        Sizes of the contiguous diagonal blocks, summing to ``n``.
    max_sweeps : int

    Returns
    -------
    BlockExpm
    """
    import scipy.linalg

    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    if A.ndim != 2 or A.shape[1] != n:
        raise ValueError(f"expected a square matrix, got shape {A.shape}")
    sizes = np.asarray(blocks, dtype=int)
    if sizes.ndim != 1 or sizes.size == 0 or np.any(sizes < 1) or int(sizes.sum()) != n:
        raise ValueError(f"blocks must be positive sizes summing to n = {n}, got {sizes.size} blocks "
                         f"summing to {int(sizes.sum())}")
    if np.any(sizes > 2):
        return _refuse(f"a diagonal block of size {int(sizes.max())} (only 1 and 2 are supported)")
    u = np.finfo(float).eps / 2.0
    norm_a = float(np.abs(A).sum(axis=0).max())
    if not math.isfinite(norm_a):
        return _refuse("not finite")
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    s2, s1 = starts[sizes == 2], starts[sizes == 1]
    D2 = np.stack([np.stack([A[s2, s2], A[s2, s2 + 1]], -1), np.stack([A[s2 + 1, s2], A[s2 + 1, s2 + 1]], -1)], 1)
    lam, Wc = np.linalg.eig(D2) if s2.size else (np.zeros((0, 2)), np.zeros((0, 2, 2)))
    rot = lam[:, 0].imag != 0.0
    # rotation blocks: T = [Re w, Im w] of the eigenvector of alpha + i beta (beta > 0), Re w _|_ Im w
    j = np.argmax(lam[rot].imag, axis=1)
    w = np.take_along_axis(Wc[rot], j[:, None, None], axis=2)[:, :, 0]
    alpha, beta = lam[rot].real[np.arange(j.size), j], lam[rot].imag[np.arange(j.size), j]
    wr, wi = w.real, w.imag
    phi = -0.5 * np.arctan2(2.0 * np.sum(wr * wi, axis=1), np.sum(wr**2 - wi**2, axis=1))
    w = w * np.exp(1j * phi)[:, None]
    Trot = np.stack([w.real, w.imag], axis=2)
    Tspl = Wc[~rot].real
    T = np.concatenate([Trot, Tspl], axis=0)
    Tinv = _inv22(T)
    norms = np.abs(T).sum(axis=1).max(axis=1), np.abs(Tinv).sum(axis=1).max(axis=1)
    if T.shape[0] and not np.all(norms[0] * norms[1] <= BLOCK_EIG_COND_LIMIT):
        return _refuse("a 2x2 diagonal block is nearly defective")
    cond_t = float(norms[0].max() * norms[1].max()) if T.shape[0] else 1.0
    mr, ms = int(rot.sum()), int((~rot).sum())
    k = 2 * mr
    # planar layout: rotation blocks' first rows, their second rows, the same for the blocks with
    # real eigenvalues (two scalars each after diagonalisation), then the 1x1 blocks
    q = np.concatenate([s2[rot], s2[rot] + 1, s2[~rot], s2[~rot] + 1, s1])
    mu = np.concatenate([lam[~rot, 0].real, lam[~rot, 1].real, A[s1, s1]])  # the scalars' eigenvalues
    At = A.take(q, axis=0).take(q, axis=1)
    _right_planar(At, Trot, 0)
    _right_planar(At, Tspl, k)
    _left_planar(_inv22(Trot), At, 0)
    _left_planar(_inv22(Tspl), At, k)
    col_at = np.abs(At).sum(axis=0)
    norm_at = float(col_at.max())
    ns = n - k
    ar, asc = np.arange(mr), np.arange(k, n)
    def neg_inv(x: np.ndarray, y: np.ndarray) -> tuple:
        """Real and imaginary parts of ``-1 / (x + i y)``."""
        d = x * x + y * y
        return -x / d, y / d

    with np.errstate(divide="ignore", invalid="ignore"):
        da = alpha[:, None] - alpha[None, :]
        gpr, gpi = neg_inv(da, beta[:, None] - beta[None, :])
        gmr, gmi = neg_inv(da, -(beta[:, None] + beta[None, :]))
        del da
        gpr[ar, ar] = gpi[ar, ar] = gmr[ar, ar] = gmi[ar, ar] = 0.0
        grr, gri = neg_inv(alpha[:, None] - mu[None, :], np.broadcast_to(beta[:, None], (mr, ns)))
        gsrr, gsri = neg_inv(mu[:, None] - alpha[None, :], np.broadcast_to(-beta[None, :], (ns, mr)))
        gss = -1.0 / (mu[:, None] - mu[None, :])
        gss[asc - k, asc - k] = 0.0
    if not all(np.isfinite(g).all() for g in (gpr, gpi, gmr, gmi, grr, gri, gsrr, gsri, gss)):
        return _refuse("two blocks share an eigenvalue")
    # ||F||_1, F = A~ - S (S: the normal forms / eigenvalues the Sylvester solves use; F also
    # holds the rounding of the diagonal blocks of A~ away from them)
    col_f = col_at.copy()
    for (i, j), ref in (((ar, ar), alpha), ((ar, mr + ar), beta), ((mr + ar, ar), -beta),
                        ((mr + ar, mr + ar), alpha), ((asc, asc), mu)):
        col_f[j] += np.abs(At[i, j] - ref) - np.abs(At[i, j])
    norm_f = float(col_f.max())
    Z = np.eye(n)
    Y = np.zeros((n, n))
    residual = math.inf
    sweeps = 0
    while True:
        R = At @ Z
        sweeps += 1
        # D' = diagonal blocks of A~ Z (Z's diagonal blocks are I): no in-block residual
        d00, d01 = R[ar, ar], R[ar, mr + ar]
        d10, d11 = R[mr + ar, ar], R[mr + ar, mr + ar]
        ds = R[asc, asc]
        za, zb = Z[:, :mr], Z[:, mr:k]
        R[:, :mr] -= za * d00 + zb * d10
        R[:, mr:k] -= za * d01 + zb * d11
        R[:, k:] -= Z[:, k:] * ds
        R[ar, ar] = R[ar, mr + ar] = R[mr + ar, ar] = R[mr + ar, mr + ar] = 0.0
        R[asc, asc] = 0.0
        norm_z = float(np.abs(Z).sum(axis=0).max())
        last, residual = residual, float(np.abs(R).sum(axis=0).max()) / (norm_at * norm_z)
        if residual <= BLOCK_RESIDUAL_TOL:
            break
        if sweeps >= max_sweeps or not residual < 0.5 * last:
            why = "stalled" if sweeps < max_sweeps else f"not converged in {max_sweeps} sweeps"
            return _refuse(f"block diagonalisation {why} (relative residual {residual:.2e})", sweeps, residual)
        # Sylvester solves, entrywise (see the notes): rotation-rotation
        r00, r01, r10, r11 = R[:mr, :mr], R[:mr, mr:k], R[mr:k, :mr], R[mr:k, mr:k]
        pr, pi = 0.5 * (r00 + r11), 0.5 * (r01 - r10)
        cpr, cpi = pr * gpr - pi * gpi, pr * gpi + pi * gpr
        pr, pi = 0.5 * (r00 - r11), 0.5 * (r01 + r10)
        cmr, cmi = pr * gmr - pi * gmi, pr * gmi + pi * gmr
        Y[:mr, :mr] = cpr + cmr
        Y[mr:k, mr:k] = cpr - cmr
        Y[:mr, mr:k] = cpi + cmi
        Y[mr:k, :mr] = cmi - cpi
        # rotation rows, scalar columns: y = (C0 - i C1) g, Y0 = Re y, Y1 = -Im y
        c0, c1 = R[:mr, k:], R[mr:k, k:]
        Y[:mr, k:] = c0 * grr + c1 * gri
        Y[mr:k, k:] = c1 * grr - c0 * gri
        # scalar rows, rotation columns: y = (C0 + i C1) g, Y0 = Re y, Y1 = Im y
        c0, c1 = R[k:, :mr], R[k:, mr:k]
        Y[k:, :mr] = c0 * gsrr - c1 * gsri
        Y[k:, mr:k] = c0 * gsri + c1 * gsrr
        Y[k:, k:] = R[k:, k:] * gss
        step = float(np.abs(Y).sum(axis=0).max())
        if not step <= BLOCK_COUPLING_LIMIT:
            return _refuse(f"coupling too strong for the gaps (correction {step:.2e})", sweeps, residual)
        Z += Y
        # the new residual without a GEMM: with D'' = blocks(A~ Z') (O(n^2)) and R + S Y - Y S = 0,
        # R' = A~ Z' - Z' D'' = F Y - Y (D'' - S) - Z (D'' - D')  (Z' = Z + Y), so
        # ||R'|| <= ||F|| ||Y|| + ||Y|| ||D'' - S|| + ||Z|| ||D'' - D'|| (+ the Sylvester rounding)
        e00 = np.einsum("ij,ji->i", At[:mr], Z[:, :mr])
        e01 = np.einsum("ij,ji->i", At[:mr], Z[:, mr:k])
        e10 = np.einsum("ij,ji->i", At[mr:k], Z[:, :mr])
        e11 = np.einsum("ij,ji->i", At[mr:k], Z[:, mr:k])
        es = np.einsum("ij,ji->i", At[k:], Z[:, k:])
        ds_new = np.concatenate([np.abs(e00 - alpha) + np.abs(e10 + beta), np.abs(e01 - beta) + np.abs(e11 - alpha),
                                 np.abs(es - mu)])
        dd_new = np.concatenate([np.abs(e00 - d00) + np.abs(e10 - d10), np.abs(e01 - d01) + np.abs(e11 - d11),
                                 np.abs(es - ds)])
        norm_z = float(np.abs(Z).sum(axis=0).max())
        r_new = (norm_f * step + step * float(ds_new.max(initial=0.0)) + norm_z * float(dd_new.max(initial=0.0))
                 + 4 * u * residual * norm_at * norm_z)
        if r_new / (norm_at * norm_z) <= BLOCK_RESIDUAL_TOL:
            d00, d01, d10, d11, ds = e00, e01, e10, e11, es
            residual = r_new / (norm_at * norm_z)
            break
    del Y, R
    # expm(A) = T Z expm(D') Z^-1 T^-1
    Dr = np.stack([np.stack([d00, d01], -1), np.stack([d10, d11], -1)], 1)
    eDr = expm_stack(Dr) if mr else Dr
    eds = np.exp(ds)
    M = Z.copy()
    _right_planar(M, eDr, 0)
    M[:, k:] *= eds[None, :]
    lu, piv = scipy.linalg.lu_factor(Z, overwrite_a=True, check_finite=False)
    rcond, info = scipy.linalg.lapack.dgecon(lu, norm_z, norm="1")
    cond = math.inf if rcond <= 0 or info != 0 else 1.0 / rcond
    if cond > BLOCK_COND_LIMIT:
        return _refuse(f"cond(Z) = {cond:.2e} too large", sweeps, residual, cond)
    Ep = scipy.linalg.lu_solve((lu, piv), M.T, trans=1, overwrite_b=True, check_finite=False).T
    _left_planar(Trot, Ep, 0)
    _left_planar(Tspl, Ep, k)
    _right_planar(Ep, _inv22(Trot), 0)
    _right_planar(Ep, _inv22(Tspl), k)
    norm_zinv = cond / norm_z
    m_s = max(1.0, float(np.abs(eDr).sum(axis=1).max()) if mr else 0.0,
              float(np.abs(eds).max()) if ns else 0.0)
    # the residual as computed misses the rounding of forming A~ and A~ Z (<= n u ||A~|| ||Z||)
    bound = cond_t * (cond**2 * m_s**2 * (residual + n * u) * norm_at * norm_z * norm_zinv + n * u * cond * m_s)
    inv = np.empty_like(q)
    inv[q] = np.arange(n)
    return BlockExpm(Ep.take(inv, axis=0).take(inv, axis=1), sweeps, residual, cond, bound, "")
