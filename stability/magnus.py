"""Magnus exponential propagators for ``x' = P(t) x`` over one period.

The period is split into ``N`` equal sub-intervals; on each one a truncated
Magnus expansion ``Omega_k`` is built from ``P`` at Gauss-Legendre points and
the sub-interval propagator is ``E_k = expm(Omega_k)``.  All ``N`` propagators
are formed at once (vectorised over sub-intervals) and the monodromy matrix is
``Phi(T) = E_N ... E_2 E_1``, multiplied by pairwise reduction (``log2 N``
batched products) rather than a sequential loop.

References
----------
.. [1] Iserles, A., Norsett, S. P., "On the solution of linear differential
       equations in Lie groups", Phil. Trans. R. Soc. A 357 (1999) 983-1019.
.. [2] Blanes, S., Casas, F., Oteo, J. A., Ros, J., "The Magnus expansion and
       some of its applications", Physics Reports 470 (2009) 151-238,
       Sec. 5 (the 4th-order and 6th-order schemes used here).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from stability.expm import _c_einsum, expm_stack, mm_soa

__all__ = [
    "MagnusScheme", "MAGNUS2", "MAGNUS4", "MAGNUS6", "magnus_factors", "ordered_product",
    "magnus_exponents", "magnus_exponents_soa", "ordered_product_soa", "ordered_product_interleaved",
]


@dataclass(frozen=True)
class MagnusScheme:
    """A Magnus scheme: its Gauss nodes (fractions of the step) and order."""

    name: str
    nodes: tuple[float, ...]
    order: int


#: 2nd order, 1 Gauss point: the exponential midpoint rule ``exp(h P(t + h/2))``.
MAGNUS2 = MagnusScheme("magnus2", (0.5,), 2)
#: 4th order, 2 Gauss points (Blanes et al. 2009, Eq. 253).
MAGNUS4 = MagnusScheme("magnus4", (0.5 - math.sqrt(3) / 6, 0.5 + math.sqrt(3) / 6), 4)
#: 6th order, 3 Gauss points (Blanes et al. 2009, Eq. 257).
MAGNUS6 = MagnusScheme(
    "magnus6", (0.5 - math.sqrt(15) / 10, 0.5, 0.5 + math.sqrt(15) / 10), 6
)


def _comm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    return A @ B - B @ A


def magnus_exponents(scheme: MagnusScheme, Pg: np.ndarray, h: float, split: bool = False):
    """Magnus exponents ``Omega_k`` from ``P`` at the Gauss points.

    Parameters
    ----------
    scheme : MagnusScheme
    Pg : ndarray, shape (N, q, n, n)
        ``P`` at the ``q`` Gauss nodes of each of the ``N`` sub-intervals.
    h : float
        Step length.
    split : bool
        Also return the commutator part ``C_k = Omega_k - h Pbar_k`` (``Pbar_k`` the Gauss mean
        of ``P`` over the sub-interval), computed directly.

    Returns
    -------
    ndarray, shape (N, n, n)
        ``Omega``; with ``split``, ``(Omega, C)``.
    """
    if scheme.order == 2:
        Om = h * Pg[:, 0]
        return (Om, np.zeros_like(Om)) if split else Om
    if scheme.order == 4:
        A1, A2 = Pg[:, 0], Pg[:, 1]
        C = (math.sqrt(3) / 12.0) * h * h * _comm(A2, A1)
        Om = 0.5 * h * (A1 + A2) + C
        return (Om, C) if split else Om
    if scheme.order == 6:
        A1, A2, A3 = Pg[:, 0], Pg[:, 1], Pg[:, 2]
        a1 = h * A2
        a2 = (math.sqrt(15) / 3.0) * h * (A3 - A1)
        a3 = (10.0 / 3.0) * h * (A3 - 2.0 * A2 + A1)
        c1 = _comm(a1, a2)
        c2 = -(1.0 / 60.0) * _comm(a1, 2.0 * a3 + c1)
        C = (1.0 / 240.0) * _comm(-20.0 * a1 - a3 + c1, a2 + c2)
        Om = a1 + a3 / 12.0 + C  # a1 + a3 / 12 = h (5 A1 + 8 A2 + 5 A3) / 18, the Gauss mean
        return (Om, C) if split else Om
    raise ValueError(f"unsupported Magnus order {scheme.order}")


def magnus_factors(
    scheme: MagnusScheme, evaluate, period: float, n_steps: int, *, return_log_det: bool = False
):
    """Sub-interval propagators ``E_k`` (shape ``(N, n, n)``), in time order.

    With ``return_log_det=True`` also return ``sum_k ln det E_k``, evaluated
    exactly as ``sum_k tr Omega_k`` (``det expm(X) = exp(tr X)``) rather than
    from the factors, whose determinants are rounding noise when a factor
    contracts a direction by more than ``1/eps``.

    Parameters
    ----------
    scheme : MagnusScheme
    evaluate : callable
        ``times (m,) -> P (m, n, n)``.
    period : float
    n_steps : int
        Number ``N`` of equal sub-intervals.
    """
    h = period / n_steps
    nodes = np.asarray(scheme.nodes)
    times = (np.arange(n_steps)[:, None] + nodes[None, :]) * h
    P = evaluate(times.ravel())
    n = P.shape[-1]
    Pg = P.reshape(n_steps, len(nodes), n, n)
    Om = magnus_exponents(scheme, Pg, h)
    E = expm_stack(Om)
    if return_log_det:
        return E, float(np.sum(np.trace(Om, axis1=1, axis2=2)))
    return E


def ordered_product(factors: np.ndarray) -> np.ndarray:
    """``E_N ... E_2 E_1`` for factors given in time order, by pairwise reduction."""
    E = factors
    while E.shape[0] > 1:
        if E.shape[0] % 2:
            # fold the last (latest) factor onto its predecessor first
            last = E[-1] @ E[-2]
            E = np.concatenate([E[:-2], last[None]], axis=0)
            if E.shape[0] == 1:
                break
        E = E[1::2] @ E[0::2]
    return E[0]


# --------------------------------------------------------------------------- matrix-major stacks
def _comm_soa(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    return mm_soa(A, B) - mm_soa(B, A)


#: Rows of :func:`magnus_exponents_soa` (order 6) on the three Gauss-node values ``A1, A2, A3``:
#: ``a1 = A2``, ``a2 = sqrt(15)/3 (A3 - A1)``, ``2 a3 = 20/3 (A3 - 2 A2 + A1)``, ``-20 a1 - a3``,
#: ``a1 + a3 / 12 = (5 A1 + 8 A2 + 5 A3) / 18`` and ``a2 / 240`` (Blanes et al. 2009, Eq. 257).
_K15 = math.sqrt(15) / 3.0
_MAGNUS6_ROWS = np.array([
    [0.0, 1.0, 0.0],
    [-_K15, 0.0, _K15],
    [20.0 / 3.0, -40.0 / 3.0, 20.0 / 3.0],
    [-10.0 / 3.0, -40.0 / 3.0, -10.0 / 3.0],
    [5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0],
    [-_K15 / 240.0, 0.0, _K15 / 240.0],
])
_MAGNUS6_ROWS.flags.writeable = False


def magnus_exponents_soa(scheme: MagnusScheme, Pg: np.ndarray, h, split: bool = False):
    """:func:`magnus_exponents` for matrix-major stacks: ``Pg`` of shape ``(q, n, n, N)``, result ``(n, n, N)``.

    ``h`` is the step length (a scalar, or one per sub-interval, shape ``(N,)``).  With ``split``,
    returns ``(Omega, C)`` where ``C`` is the commutator part of the exponent, ``Omega - h Pbar`` with
    ``Pbar`` the Gauss-quadrature mean of ``P`` over the sub-interval (computed directly, not as that
    difference; zero for ``magnus2``).
    """
    if scheme.order == 2:
        Om = h * Pg[0]
        return (Om, np.zeros_like(Om)) if split else Om
    if scheme.order == 4:
        A1, A2 = Pg[0], Pg[1]
        C = (math.sqrt(3) / 12.0) * (h * h) * _comm_soa(A2, A1)
        Om = 0.5 * h * (A1 + A2) + C
        return (Om, C) if split else Om
    if scheme.order == 6:
        # the linear combinations of the nodes that enter, in one product (6 x 3) @ (3 x n n N):
        # a1, a2, 2 a3, -20 a1 - a3, the Gauss mean a1 + a3 / 12 and a2 / 240 (before the factor h)
        q = Pg.shape[0]
        rows = (_MAGNUS6_ROWS @ Pg.reshape(q, -1)).reshape((6,) + Pg.shape[1:])
        rows *= h
        a1, a2, two_a3, outer, mean, a2_240 = rows
        c1 = _comm_soa(a1, a2)
        two_a3 += c1
        c2 = _comm_soa(a1, two_a3)  # -60 times the c2 of the scheme
        outer += c1
        c2 *= -1.0 / 14400.0
        c2 += a2_240  # (a2 + c2) / 240
        C = _comm_soa(outer, c2)  # (1 / 240) [-20 a1 - a3 + c1, a2 + c2]
        mean += C
        return (mean, C) if split else mean
    raise ValueError(f"unsupported Magnus order {scheme.order}")


def ordered_product_soa(factors: np.ndarray, blocks: int = 1) -> np.ndarray:
    """:func:`ordered_product` for a matrix-major stack ``(n, n, N)`` in time order; returns ``(n, n)``.

    With ``blocks = b``, the stack holds ``b`` interleaved sequences (factor ``k``
    of sequence ``j`` at index ``k * b + j``), all reduced together; returns
    ``(n, n, b)``.
    """
    n = factors.shape[0]
    E = factors.reshape(n, n, -1, blocks)
    while E.shape[2] > 1:
        if E.shape[2] % 2:
            last = _c_einsum("ijkb,jlkb->ilkb", E[:, :, -1:], E[:, :, -2:-1])
            E = np.concatenate([E[:, :, :-2], last], axis=2)
            if E.shape[2] == 1:
                break
        E = _c_einsum("ijkb,jlkb->ilkb", E[:, :, 1::2], E[:, :, 0::2])
    return E[:, :, 0, 0] if blocks == 1 else E[:, :, 0, :]


def ordered_product_interleaved(E: np.ndarray) -> np.ndarray:
    """Pairwise ordered products of ``b`` sequences stacked as ``(N, b, n, n)`` (time order along
    the first axis); returns ``(b, n, n)``, the same pairing as :func:`ordered_product_soa`.

    ``matmul`` on the strided halves of a contiguous ``(N, b, n, n)`` stack costs less than
    ``einsum`` on strided matrix-major views (the products agree to rounding, not bitwise)."""
    while E.shape[0] > 1:
        if E.shape[0] % 2:
            last = np.matmul(E[-1:], E[-2:-1])
            E = np.concatenate([E[:-2], last], axis=0)
            if E.shape[0] == 1:
                break
        E = np.matmul(E[1::2], E[0::2])
    return E[0]
