"""Frozen-modal coordinates for the Floquet propagator of a stiff periodic system.

Public entry points: :class:`FrozenModalSystem` and :func:`modal_floquet`.

Why
---
The exponential midpoint product ``prod exp(h P(t_k + h/2))`` is exact for a
constant ``P``; its error comes from how ``P`` changes *within* a step.  In a
linearised flexible multibody model the stiff part of ``P`` (axial and high
bending frequencies, ``|lambda|`` up to ~1e5 1/s) keeps nearly constant frozen
*eigenvalues* along the orbit (measured on the single link: ``|Im lambda|``
varies by < 1e-3 relative over the period), but its frozen *eigenvectors*
turn in the state space with the motion, in any coordinates built from the
model (the hand-derived hub frame as much as the generic co-rotating null-space
basis).  Every step boundary then moves the quasi-static equilibrium of the
stiff modes abruptly; the frozen step excites them (a "kick" of phase
``omega h``), and the multipliers converge erratically (measured, single link,
2 elements, 8 pi: the largest damped multiplier 1.2e-4 off at 256 steps, 3e-7 at
4096; the hub multiplier 1.1e-2 off at 512 steps with a step-doubling estimate
of 4.5e-4; 8 elements need even more).

In the frozen-modal coordinates ``x = V(t) y`` (``V(t)`` a smooth
T-periodic real basis of the eigenvectors of ``P(t)``, complex pairs as their
real and imaginary parts),

    y' = P_hat(t) y,     P_hat = V^-1 (P V - V'),

``P_hat`` is nearly block diagonal with slowly varying 1x1 / 2x2 blocks (the
frozen eigenvalues, whose blocks commute with each other at different times);
only the small coupling ``-V^-1 V'`` (rate of turn of the mode shapes) varies
within a step.  Measured on the 8-element single link (Table 3 gains), relative
error of the hub multiplier with 128 midpoint steps: 1.5e-9, 9e-7, 4.3e-5,
1.7e-4 at 2, 4, 6, 8 pi (512 steps in the model's coordinates: 6.5e-5 at 4 pi,
5.2e-3 at 8 pi), now converging cleanly at order 2 (ratio 3.9-4.0 per
doubling), so that Richardson extrapolation (:func:`modal_floquet`,
``extrapolate=True``) lifts it to order 4.  A second frame built the same way on
``P_hat`` (:func:`modal_system`, a superadiabatic iteration) removes the
first-order coupling between the modes; with both, 128 steps extrapolated leave
5.9e-13, 3.2e-9, 7.4e-8, 3.3e-7 against the same linearisation converged (see
:data:`MODAL_LEVELS` and :data:`linearize.analysis.DEFAULT_PROPAGATOR_STEPS`).

Exactness
---------
For *any* smooth, T-periodic, invertible ``V(t)`` the multipliers of ``P_hat``
equal those of ``P`` (``Phi(T) = V(0) Phi_hat(T) V(0)^-1``): ``V`` only has to
be a good basis, not exact eigenvectors.  Here ``V`` is the trigonometric
interpolant of eigenvector samples and ``V'`` its *exact* derivative, so the
transformation is an exact similarity whatever the sample count.  The frozen
eigenvalues are grouped into clusters by modulus: a cut between two consecutive
moduli (sorted) wherever they stay apart over the whole period by many times
their own variation (:data:`CLUSTER_MARGIN`) or by 5 % relative, and by more
than the orbit frequency (:data:`CLUSTER_MIN_GAP`), so that each cluster's invariant subspace
is a smooth function of ``t`` (a crossing, or the hub pair turning from complex
to real and back at 6 pi, stays inside one cluster; conjugate pairs always do;
see :func:`_cluster_bounds`).  Each cluster's real basis
(real eigenvectors, real and imaginary parts of the complex ones) is continued
from sample to sample with unit projection on the previous left basis (a
discrete parallel transport); the holonomy after one lap (a small real block per
cluster) is removed with ``expm(-G t / T)``, ``G`` its real logarithm, as in
:func:`linearize.constrained.null_space_basis`.  A continuation that does not
close (a block without a real logarithm, a subspace turning by ~90 degrees
between samples, a nearly singular basis) raises :class:`ModalBasisError`;
:func:`modal_system` retries with more samples, and :func:`modal_floquet` then
propagates ``P`` itself.

Cost of the basis
-----------------
A full ``eig`` per sample (:func:`_eig_basis`) is the reference construction
and the fallback.  By default (:data:`BASIS_METHODS`) the first frame takes one
``eig`` at ``t = 0`` and continues the basis by Newton steps ``V <- V (I + X)``,
``X`` the first-order (Sylvester) correction of ``V^-1 P_k V`` between clusters
(:func:`_continued_basis`, :func:`_first_order`: a solve and a few products per
step instead of an ``eig``), and a nested frame, whose ``P_hat`` is already
nearly block diagonal, is ``V = I + X`` at ``O(n^2)`` per sample
(:func:`_perturbed_basis`).  Measured on the single link at Omega = 2 pi with the
Table 3 gains (two frames, 32 samples, CPU s on the shared 2-core machine):
64 elements (516 states) 23.1 s (29.7 s at load 5) with an ``eig`` per sample
and the former 5 % gap alone (a cluster of 423 modes), 7.4 s now (clusters of
<= 2, nested frame on 16 of the 32 samples; ``benchmarks/scale.py``); the
multipliers of both constructions agree to 5e-10 (64 elements, 144 steps, and
7e-10 with 288 steps).

Cost of the propagation
-----------------------
:func:`modal_floquet` propagates nested frames in their composite basis
(:class:`CollapsedModalSystem`, ``U = V1 D2 V2`` from one trigonometric table of
``K1 + K2`` samples): one product and one LU solve per time instead of one per
frame.  Measured (CPU s, 16 times of ``P_hat``, 32 elements, 260 states): frame by
frame 0.20, composite 0.13 (its table: 0.26 once); the two agree to 6e-12 relative
(``cond(U) = 7.6e4``).  ``benchmarks/scale.py --frame modal --steps 144`` dense stage
16 / 32 elements 1.30 / 4.68 s -> 0.96 / 4.50 s, dominant multiplier moved by
1.2e-11 / 7e-11 (estimates 7.5e-10 / 1.1e-9); 64 elements 19.3 s (one run, load ~2-4).

References
----------
.. [1] Iserles, A., "On the global error of discretization methods for
       highly-oscillatory ordinary differential equations", BIT 42 (2002)
       561-599 (the error of Magnus methods for oscillatory systems, and
       changes of frame that remove it).
"""
from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, fields, replace
from typing import Any, Optional

import numpy as np
import scipy.linalg

from stability.floquet import FloquetResult
from stability.periodic import PeriodicMatrixFunction

__all__ = ["CollapsedModalSystem", "FrozenModalSystem", "ModalBasisError", "ModalFloquetResult", "modal_floquet",
           "modal_system",
           "DEFAULT_MODAL_SAMPLES", "FALLBACK_METHOD", "MODAL_LEVELS", "CLUSTER_MARGIN", "CLUSTER_MIN_GAP",
           "CLUSTER_RELATIVE_GAP", "BASIS_METHODS"]

logger = logging.getLogger(__name__)

#: Samples of the eigenvector basis per period (:func:`modal_system` doubles them, up to
#: :data:`MAX_MODAL_SAMPLES`, when the continuation fails).  The basis only has to be smooth,
#: not exact (the similarity is exact for any ``V``): measured on the 8-element single link
#: 16 and 32 samples give the same multipliers to 1e-9, but on the two-link arm (4 pi, no gains)
#: 16 samples leave 9e-4 at 128 steps where 32 leave 1.6e-5.
DEFAULT_MODAL_SAMPLES = 32
MAX_MODAL_SAMPLES = 64
#: Samples of a nested frame (:func:`modal_system`), when they divide the first frame's: its basis
#: ``I + X`` follows the slow coupling of the first frame, not the model's mode shapes.  Measured
#: with 16 against 32: single link 32 elements (144 steps) the same multipliers to 1e-10 of a
#: 288-step reference; two-link arm (4 pi, kp = (20, 10), kd = (5, 2)) dominant 128-step error
#: 9e-6 against 1.6e-5; the nested frame's cost halves (~1 s at 64 elements).
NESTED_MODAL_SAMPLES = 16
#: Largest condition number (1-norm estimate) of a sampled basis ``V(t_k)`` (balanced) accepted;
#: beyond it the eigenvectors are nearly dependent (a near-defective ``P``) and the similarity
#: loses digits.
MAX_CONDITION = 1e8
#: Two consecutive frozen moduli (sorted) start separate clusters when the gap between them
#: over the whole period, ``g = min_t |lambda_{i+1}| - max_t |lambda_i|``, exceeds
#: ``CLUSTER_MIN_GAP`` times the orbit frequency ``2 pi / T`` and either ``CLUSTER_MARGIN`` times
#: their own variation over the period (the larger spread ``max_t - min_t`` of the two) or
#: ``CLUSTER_RELATIVE_GAP`` of the lower one (the former rule alone).  See :func:`_cluster_bounds`.
#: Measured on the single link (Omega = 2 pi, Table 3 gains, two frames, 144 steps extrapolated),
#: largest cluster / error estimate with the relative gap alone: 16 el 27 / 5.7e-5, 32 el
#: 133 / 0.47, 64 el 423 / 0.7; with this rule 2 / 7.5e-10, 2 / 1.3e-7, 2 / 1.3e-5 (1.4e-9 at 288
#: steps).  The spread rule alone merged the two-link arm's slow modes (|lambda| 3 ... 205, varying
#: by up to 50 %) with its stiff ones (1442 ... 3025) into one cluster of 10 and moved its dominant
#: multiplier (4 pi, kp = (20, 10), kd = (5, 2)) by 1.3e-3: hence the union.  ``CLUSTER_MIN_GAP =
#: 4`` merged the two real hub eigenvalues of the 2-element link at 4 pi (gap 2.5 Omega) and made
#: their midpoint error 3x larger: merging never helps a smooth pair.
CLUSTER_MARGIN = 10.0
CLUSTER_RELATIVE_GAP = 0.05
CLUSTER_MIN_GAP = 1.0
#: How :class:`FrozenModalSystem` builds its basis samples: ``"eig"`` a full eigen-decomposition per
#: sample (:func:`_eig_basis`); ``"perturbation"`` first-order perturbation theory: for a frame
#: nested in another (``P`` nearly block diagonal) ``V = I + X`` at ``O(n^2)`` per sample
#: (:func:`_perturbed_basis`), for a first frame a Newton continuation from one ``eig``
#: (:func:`_continued_basis`); ``"auto"`` (default) the latter, falling back to ``"eig"`` when it
#: does not apply.  Measured on the single link, 64 elements (516 states): see the module notes.
BASIS_METHODS = ("auto", "eig", "perturbation")


class ModalBasisError(ArithmeticError):
    """No smooth periodic frozen-eigenvector basis could be continued along the period (says why)."""


#: The one fallback policy of the package when no frozen-modal basis exists
#: (:class:`ModalBasisError`, e.g. a mode whose damping crosses critical within the period):
#: :func:`modal_floquet` warns (``RuntimeWarning``) and runs :func:`stability.floquet`'s
#: *adaptive* engine (``n_steps=None``, the caller's ``rtol``) with this method in ``P``'s own
#: coordinates, so that the result carries a checked Richardson estimate, never a fixed step count
#: outside its asymptotic range.  For a stiff flexible model this can be slow or exceed the work
#: limit (:class:`stability.FloquetError`): an error, not a silently inaccurate answer.
FALLBACK_METHOD = "magnus6"


@dataclass(frozen=True)
class ModalFloquetResult(FloquetResult):
    """:class:`~stability.FloquetResult` of :func:`modal_floquet`, with the frame it was propagated in.

    Attributes
    ----------
    frame : {"modal", "model"}
        ``"modal"``: frozen-modal coordinates (``modal_levels`` nested frames);
        ``"model"``: the fallback (:data:`FALLBACK_METHOD`, adaptive) in ``P``'s own coordinates.
    modal_levels : int
        Nested frozen-modal frames used (0 for the fallback).
    fallback_reason : str
        Why no basis was built (the :class:`ModalBasisError` message), ``""`` otherwise.
    """

    frame: str = "modal"
    modal_levels: int = 0
    fallback_reason: str = ""

    def to_dict(self) -> dict:
        """:meth:`FloquetResult.to_dict` with ``frame``, ``modal_levels`` and ``fallback_reason``."""
        return dict(super().to_dict(), frame=self.frame, modal_levels=self.modal_levels,
                    fallback_reason=self.fallback_reason)


def _with_frame(res: FloquetResult, frame: str, levels: int, reason: str = "") -> ModalFloquetResult:
    """``res`` as a :class:`ModalFloquetResult` recording the frame (its certification recomputed
    from its own estimates: the extrapolated and checked solves replace them)."""
    from stability.floquet import recertify

    res = recertify(res)
    values = {f.name: getattr(res, f.name) for f in fields(FloquetResult) if f.init}
    return ModalFloquetResult(**values, frame=frame, modal_levels=levels, fallback_reason=reason)


def _levels(system: Any) -> int:
    """Number of nested :class:`FrozenModalSystem` frames of ``system``."""
    n = 0
    while isinstance(system, FrozenModalSystem):
        n, system = n + 1, system.original
    return n


def _trig_coefficients(samples: np.ndarray) -> np.ndarray:
    """Real Fourier coefficients (axis 0) of equispaced periodic samples (``N`` even):
    ``y(t) = sum_k a_k cos(k w t) - b_k sin(k w t)``, returned as complex ``a_k + i b_k``."""
    N = samples.shape[0]
    c = np.fft.rfft(samples, axis=0) / N
    w = np.full(N // 2 + 1, 2.0)
    w[0] = 1.0
    w[-1] = 1.0
    return c * w.reshape((-1,) + (1,) * (samples.ndim - 1))


def _trig_table(coef: np.ndarray) -> np.ndarray:
    """``coef`` (complex ``a_k + i b_k``, shape ``(K, ...)``) as one real ``(2 K, prod(...))`` table
    ``[a; b]`` for :func:`_trig_rows`."""
    flat = coef.reshape(coef.shape[0], -1)
    return np.ascontiguousarray(np.concatenate([flat.real, flat.imag]))


def _trig_rows(K: int, period: float, t: np.ndarray, derivative: bool) -> np.ndarray:
    """Rows ``[cos(k w t), -sin(k w t)]`` (or their time derivatives ``[-k w sin, -k w cos]``),
    shape ``(m, 2 K)``: the interpolant is ``rows @ [a; b]`` in real arithmetic."""
    k = np.arange(K)
    w = 2.0 * np.pi / period
    arg = w * np.outer(t, k)
    c, s = np.cos(arg), np.sin(arg)
    if derivative:
        return np.concatenate([-(w * k) * s, -(w * k) * c], axis=1)
    return np.concatenate([c, -s], axis=1)


def _trig_eval(coef: np.ndarray, period: float, t: np.ndarray, derivative: bool = False) -> np.ndarray:
    """The trigonometric interpolant (or its exact time derivative) at times ``t``.

    Real arithmetic: ``y(t) = sum_k a_k cos(k w t) - b_k sin(k w t)`` is one real product
    ``(m, 2K) @ (2K, size)`` (a quarter of the flops of the complex phase product and no
    complex temporaries; the same sums, so equal to rounding)."""
    rows = _trig_rows(coef.shape[0], period, t, derivative)
    return (rows @ _trig_table(coef)).reshape((t.size,) + coef.shape[1:])


def _real_log(H: np.ndarray) -> np.ndarray:
    """Real logarithm of a holonomy block (raises :class:`ModalBasisError` if none is near)."""
    if H.shape == (1, 1):
        if not H[0, 0] > 0:
            raise ModalBasisError("a real frozen eigenvector reverses over one period (no periodic real basis)")
        return np.log(H)
    G = scipy.linalg.logm(H)
    if np.iscomplexobj(G):
        if np.max(np.abs(G.imag)) > 1e-8 * max(1.0, float(np.max(np.abs(G)))):
            raise ModalBasisError("the holonomy of a frozen invariant subspace has no real logarithm")
        G = G.real
    return G


def _cluster_bounds(mods: np.ndarray, omega: float) -> list:
    """``[(start, stop), ...]``: clusters of the frozen moduli ``mods`` (``(K, n)``, sorted per sample).

    A cut between ``i`` and ``i + 1`` where the gap over the whole period
    ``g = min_t m_{i+1} - max_t m_i`` exceeds ``CLUSTER_MIN_GAP * omega`` and either
    ``CLUSTER_MARGIN * max(s_i, s_{i+1})`` (``s`` the spread ``max_t m - min_t m`` of
    each modulus over the period) or ``CLUSTER_RELATIVE_GAP * max_t m_i`` (a gap large
    against the moduli themselves, the former rule).  Why the spread rule: the rate at which a cluster's
    invariant subspace turns is ``~ |P'| / g`` (first-order perturbation), and
    ``|P'|`` shows in the moduli's own spread; a gap many times the spread keeps
    the subspaces of both sides smooth over the period, and a gap several times
    the orbit frequency keeps the first-order coupling ``-V^-1 V'`` between them
    (``~ omega x turn``) small against ``g``, so that the next frozen-modal frame
    removes it (a gap of only a few ``omega`` still leaves the second frame a small
    coupling ``~ omega x turn / g``).  A crossing (``g <= 0``) or a pair turning from complex to real
    never cuts.  (A fixed relative gap, the former rule, merged the interleaving
    bending ``~ k^2`` and axial ``~ k`` frequencies of fine meshes, whose moduli
    lie < 5 % apart but vary by < 1e-5 relative, into clusters of 100+ modes; it
    stays as the alternative because the spread rule alone merges slow modes that
    vary by tens of % with stiff ones far above, see :data:`CLUSTER_MARGIN`.)
    """
    lo, hi = mods.min(axis=0), mods.max(axis=0)
    cuts = [i + 1 for i in np.flatnonzero(_separated(lo, hi, omega))]
    return list(zip([0] + cuts, cuts + [mods.shape[1]]))


def _separated(lo: np.ndarray, hi: np.ndarray, omega: float) -> np.ndarray:
    """``(n - 1,)`` booleans: may consecutive moduli ``i``, ``i + 1`` (ranges ``[lo, hi]`` over the
    period, sorted) be cut apart (the rule of :func:`_cluster_bounds`)."""
    spread = hi - lo
    gap = lo[1:] - hi[:-1]
    own = gap > CLUSTER_MARGIN * np.maximum(spread[1:], spread[:-1])
    relative = lo[1:] > (1.0 + CLUSTER_RELATIVE_GAP) * hi[:-1]
    return (own | relative) & (gap > CLUSTER_MIN_GAP * omega)


class _PerturbationFailed(ArithmeticError):
    """The first-order basis does not apply (a coupling not small against its gap, a defective block)."""


#: Largest entry of the first-order correction ``X`` of a nested frame (:func:`_perturbed_basis`)
#: accepted; its error is ``O(X^2)`` (relative), which only makes the basis less exact, never the
#: similarity.  Measured on the 32-element link (16 nested samples, largest entry 0.068): with 0.2
#: the first-order frame, with 0.05 the eig fallback (1.44 against 2.21 s CPU), both within
#: 1.7e-10 of a 288-step reference at 144 steps.
MAX_FIRST_ORDER = 0.2


def _block_right(A: np.ndarray, S: dict) -> np.ndarray:
    """``A @ blockdiag(S)`` for a block diagonal given as ``S = {size: (idx, blocks)}`` (``idx`` the
    ``(m, s)`` columns of each block, ``blocks`` ``(m, s, s)``): ``O(n^2 s)``, no dense product."""
    out = np.empty(A.shape, dtype=np.result_type(A, *[b for _, b in S.values()]))
    for idx, blocks in S.values():
        out[:, idx] = np.matmul(A[:, idx].transpose(1, 0, 2), blocks).transpose(1, 0, 2)
    return out


def _inv2(A: np.ndarray) -> tuple:
    """Inverses of a batch of 2x2 matrices (``(..., 2, 2)``) in closed form, and their determinants."""
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    inv = np.empty_like(A)
    inv[..., 0, 0], inv[..., 1, 1] = A[..., 1, 1], A[..., 0, 0]
    inv[..., 0, 1], inv[..., 1, 0] = -A[..., 0, 1], -A[..., 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return inv / det[..., None, None], det


def _mul2(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for broadcast batches of 2x2 matrices, entry by entry (numpy's batched ``matmul`` of
    2x2 matrices costs ~100x more per product)."""
    a00, a01, a10, a11 = A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1]
    b00, b01, b10, b11 = B[..., 0, 0], B[..., 0, 1], B[..., 1, 0], B[..., 1, 1]
    return np.stack([np.stack([a00 * b00 + a01 * b10, a00 * b01 + a01 * b11], axis=-1),
                     np.stack([a10 * b00 + a11 * b10, a10 * b01 + a11 * b11], axis=-1)], axis=-2)


def _sylvester22(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """:func:`_sylvester` for 2x2 blocks, written entry by entry (``p_B(A)`` from ``A``'s own square)."""
    a00, a01, a10, a11 = A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1]
    b00, b01, b10, b11 = B[..., 0, 0], B[..., 0, 1], B[..., 1, 0], B[..., 1, 1]
    c00, c01, c10, c11 = C[..., 0, 0], C[..., 0, 1], C[..., 1, 0], C[..., 1, 1]
    tr, det = b00 + b11, b00 * b11 - b01 * b10
    ta, cross = a00 + a11, a01 * a10
    p00 = a00 * a00 + cross - tr * a00 + det
    p11 = a11 * a11 + cross - tr * a11 + det
    p01 = a01 * (ta - tr)
    p10 = a10 * (ta - tr)
    r00 = a00 * c00 + a01 * c10 + c00 * b00 + c01 * b10 - tr * c00
    r01 = a00 * c01 + a01 * c11 + c00 * b01 + c01 * b11 - tr * c01
    r10 = a10 * c00 + a11 * c10 + c10 * b00 + c11 * b10 - tr * c10
    r11 = a10 * c01 + a11 * c11 + c10 * b01 + c11 * b11 - tr * c11
    d = p00 * p11 - p01 * p10
    X = np.empty(np.broadcast_shapes(A.shape, B.shape, C.shape))
    X[..., 0, 0] = (p11 * r00 - p01 * r10) / d
    X[..., 0, 1] = (p11 * r01 - p01 * r11) / d
    X[..., 1, 0] = (p00 * r10 - p10 * r00) / d
    X[..., 1, 1] = (p00 * r11 - p10 * r01) / d
    return X


def _sylvester(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``X`` with ``A X - X B = C`` for batches (``A`` ``(..., p, p)``, ``B`` ``(..., q, q)``, ``C``
    ``(..., p, q)``), in closed form for ``p, q <= 2`` (real arithmetic, elementwise over the batch):
    ``(p, q) = (2, 2)``: ``X = p_B(A)^-1 (A C + C B - tr(B) C)`` with ``p_B(z) = z^2 - tr(B) z + det B``
    (from ``A^2 X - X B^2 = A C + C B`` and Cayley-Hamilton for ``B``); else by the Kronecker form.
    A common eigenvalue of ``A`` and ``B`` gives non-finite entries."""
    p, q = A.shape[-1], B.shape[-1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if p == 1 and q == 1:
            return C / (A - B)
        if p == 2 and q == 1:
            inv, _ = _inv2(A - B[..., 0, 0, None, None] * np.eye(2))
            return _mul2(inv, np.concatenate([C, np.zeros_like(C)], axis=-1))[..., :1]
        if p == 1 and q == 2:
            inv, _ = _inv2(A[..., 0, 0, None, None] * np.eye(2) - B)
            return _mul2(np.concatenate([C, np.zeros_like(C)], axis=-2), inv)[..., :1, :]
        if p == 2 and q == 2:
            return _sylvester22(A, B, C)
        shape = np.broadcast_shapes(A.shape[:-2], B.shape[:-2], C.shape[:-2])
        kron = (np.einsum("...ij,kl->...ikjl", A, np.eye(q)) - np.einsum("ij,...lk->...ikjl", np.eye(p), B))
        kron = np.broadcast_to(kron.reshape(kron.shape[:-4] + (p * q, p * q)), shape + (p * q, p * q))
        rhs = np.broadcast_to(C, shape + (p, q)).reshape(shape + (p * q,))
        try:
            return np.linalg.solve(kron, rhs[..., None])[..., 0].reshape(shape + (p, q))
        except np.linalg.LinAlgError:
            return np.full(shape + (p, q), np.inf)


def _first_order(M: np.ndarray, index: dict, labels: np.ndarray) -> tuple:
    """First-order invariant subspaces of ``M`` (real, nearly block diagonal over the clusters).

    With ``D`` the cluster blocks of ``M`` and ``E = M - D``: ``X`` (zero on the cluster blocks)
    solves ``D X - X D = -E``, so that ``(I + X)^-1 M (I + X) = D + O(E X)``: block diagonal to
    first order (``I + X`` keeps unit projection on the current cluster bases, a parallel
    transport).  One small Sylvester equation ``D_a X_ab - X_ab D_b = -E_ab`` per pair of clusters,
    solved in closed form for blocks of size <= 2 (:func:`_sylvester`), batched over the pairs
    (clusters of one size made contiguous by one permutation): ``O(n^2)`` real operations instead
    of a full ``eig``.  Returns ``(X, mu)``, ``mu`` the block eigenvalues (``(n,)``, cluster order).
    """
    n = M.shape[0]
    mu = np.empty(n, dtype=complex)
    perm = np.concatenate([idx.ravel() for idx in index.values()])
    Mp = M[np.ix_(perm, perm)]
    Xp = np.empty_like(Mp)
    offsets, start = {}, 0
    for size, idx in index.items():
        offsets[size] = (start, len(idx))
        start += idx.size
    blocks = {}
    for size, (o, m) in offsets.items():
        diag = Mp[o:o + m * size, o:o + m * size].reshape(m, size, m, size)
        blocks[size] = diag[np.arange(m), :, np.arange(m), :]  # (m, size, size)
        mu[index[size]] = np.linalg.eigvals(blocks[size])
    for sa, (oa, ma) in offsets.items():
        for sb, (ob, mb) in offsets.items():
            E = Mp[oa:oa + ma * sa, ob:ob + mb * sb].reshape(ma, sa, mb, sb).transpose(0, 2, 1, 3)
            Xab = _sylvester(blocks[sa][:, None], blocks[sb][None, :], -E)
            if sa == sb:
                Xab[np.arange(ma), np.arange(ma)] = 0.0  # a cluster with itself
            Xp[oa:oa + ma * sa, ob:ob + mb * sb] = Xab.transpose(0, 2, 1, 3).reshape(ma * sa, mb * sb)
    if not np.all(np.isfinite(Xp)):
        raise _PerturbationFailed("a coupling between two clusters with a common eigenvalue")
    X = np.empty_like(M)
    X[np.ix_(perm, perm)] = Xp
    return X, mu


def _merge_cuts(mu: np.ndarray, bounds: list, omega: float) -> list:
    """``bounds`` with the cuts that break the rule of :func:`_cluster_bounds` removed, judged on
    the block eigenvalues ``mu`` (``(K, n)``, cluster order) over the period."""
    mods = np.abs(mu)
    for a, b in bounds:
        mods[:, a:b] = np.sort(mods[:, a:b], axis=1)
    lo, hi = mods.min(axis=0), mods.max(axis=0)
    cuts = [a for a, _ in bounds[1:]]
    ok = _separated(lo, hi, omega)
    # a cut also needs the whole of both neighbouring clusters apart (they need not stay sorted)
    keep = []
    for i, c in enumerate(cuts):
        a = bounds[i][0]
        b = bounds[i + 2][0] if i + 2 < len(bounds) else mods.shape[1]
        if ok[c - 1] and mods[:, c:b].min() > mods[:, a:c].max():
            keep.append(c)
    return list(zip([0] + keep, keep + [mods.shape[1]]))


def _perturbed_basis(Pb: np.ndarray, parent: list, omega: float) -> tuple:
    """Basis samples ``V_k = I + X_k`` and cluster bounds of a frame nested in another.

    ``Pb`` (``(K, n, n)``) is expressed in a frozen-modal frame with cluster bounds ``parent``,
    so it is nearly block diagonal; :func:`_first_order` gives ``X_k`` at each sample, and the
    samples are periodic by construction (no continuation, no holonomy).  The clusters are the
    parent's, merged (and the samples redone) where the block eigenvalues over the period break
    the rule of :func:`_cluster_bounds`.  Raises :class:`_PerturbationFailed` when a correction is
    not small (``> MAX_FIRST_ORDER``).  (A continuation of the *first* frame by the same step,
    ``V_k = V_{k-1} (I + X_k)``, was tried: on the single link the stiff modes' eigenvectors turn
    by ~0.25 between 32 samples, too far for one first-order step.)
    """
    K, n = Pb.shape[0], Pb.shape[1]
    bounds = list(parent)
    for _ in range(4):
        index = _size_groups(bounds)
        labels = np.repeat(np.arange(len(bounds)), [b - a for a, b in bounds])
        mus = np.empty((K, n), dtype=complex)
        V = np.empty((K, n, n))
        for k in range(K):
            X, mus[k] = _first_order(Pb[k], index, labels)
            worst = float(np.abs(X).max())
            if not worst <= MAX_FIRST_ORDER:
                raise _PerturbationFailed(f"first-order correction {worst:.1e} > {MAX_FIRST_ORDER}")
            V[k] = X
            V[k].flat[:: n + 1] += 1.0
        merged = _merge_cuts(mus, bounds, omega)
        if merged == bounds:
            return V, bounds
        bounds = merged
    raise _PerturbationFailed("the clusters did not settle")


def _size_groups(bounds: list) -> dict:
    """``{size: (clusters, size) index array}``: clusters grouped by size (batched small-block work)."""
    groups: dict = {}
    for a, b in bounds:
        groups.setdefault(b - a, []).append(a)
    return {size: (np.array(starts)[:, None] + np.arange(size)[None, :]) for size, starts in groups.items()}


def _real_columns(lams: np.ndarray, Ws: np.ndarray, bounds: list) -> np.ndarray:
    """Real basis of each cluster's invariant subspace from eigenvectors ``Ws`` (``(K, n, n)``,
    columns sorted as ``lams``): Re and Im of the eigenvectors with Im lambda > 0, and the real
    eigenvectors (conjugates share a modulus, hence a cluster)."""
    K, n = lams.shape
    pick = np.empty((K, n), dtype=int)
    part = np.empty((K, n), dtype=bool)  # True: take Im, False: take Re
    for k in range(K):
        lam = lams[k]
        cols, ims = [], []
        for a, b in bounds:
            upper = [j for j in range(a, b) if lam[j].imag > 0]
            real = [j for j in range(a, b) if lam[j].imag == 0]
            if 2 * len(upper) + len(real) != b - a:
                raise ModalBasisError("a cluster of frozen eigenvalues is not closed under conjugation")
            for j in upper:
                cols += [j, j]
                ims += [False, True]
            cols += real
            ims += [False] * len(real)
        pick[k], part[k] = cols, ims
    return np.where(part[:, None, :], np.take_along_axis(Ws.imag, pick[:, None, :], axis=2),
                    np.take_along_axis(Ws.real, pick[:, None, :], axis=2))


def _batched_inverse(A: np.ndarray) -> tuple:
    """Inverses of a batch ``(m, s, s)`` and each one's growth ``max|A^-1| max|A|`` (a cheap
    condition measure); a singular batch gives ``inf`` entries and growth, never an exception."""
    with np.errstate(all="ignore"):
        try:
            inv = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            inv = np.full_like(A, np.inf)
        growth = np.abs(inv).max(axis=(1, 2)) * np.abs(A).max(axis=(1, 2))
    return inv, growth


#: A holonomy block whose eigenvector matrix ``S`` (or that of its real logarithm) has a growth
#: ``max|S^-1| max|S|`` above this is *defective* (a Jordan block, e.g. the free spin of a hanging
#: 3D pendulum: a zero frozen eigenvalue pair): its ``expm(-G tau)`` is formed directly
#: (:func:`scipy.linalg.expm` per sample) instead of through ``S diag(h^-tau) S^-1``.
DEFECTIVE_GROWTH = 1e6


def _block_log(H: np.ndarray) -> tuple:
    """Eigen-decompositions ``(h, S, S^-1)`` of a batch of holonomy blocks (``(m, s, s)``) with a real
    logarithm (``log H = S diag(log h) S^-1`` real), and ``logs``: ``{c: G_c}`` for the blocks whose
    decomposition is ill-conditioned (:data:`DEFECTIVE_GROWTH`): their real logarithm
    (:func:`_real_log`), exponentiated directly by :func:`_remove_holonomy` (their ``h, S, S^-1``
    entries are placeholders ``1, I, I``).  Raises :class:`ModalBasisError` (never ``LinAlgError``)
    when a block has no real logarithm."""
    h, S = np.linalg.eig(H)
    Sinv, growth = _batched_inverse(S)
    real = np.abs(h.imag) <= 1e-12 * np.abs(h)
    if np.any(real & (h.real <= 0)):
        raise ModalBasisError("a frozen invariant subspace has a holonomy without a real logarithm "
                              "(a real eigenvector reverses over one period)")
    logs = {}
    eye = np.eye(H.shape[1])
    for c in np.flatnonzero(~(growth <= DEFECTIVE_GROWTH)):
        G = _real_log(H[c])
        if not np.all(np.isfinite(G)):
            raise ModalBasisError("the holonomy of a frozen invariant subspace has no finite real logarithm")
        g, T = np.linalg.eig(G)
        Tinv, t_growth = _batched_inverse(T[None])
        if t_growth[0] <= DEFECTIVE_GROWTH:
            h[c], S[c], Sinv[c] = np.exp(g), T, Tinv[0]
        else:
            logs[int(c)] = G
            h[c], S[c], Sinv[c] = 1.0, eye, eye
    return h, S, Sinv, logs


def _remove_holonomy(V: np.ndarray, index: dict, tau: np.ndarray) -> np.ndarray:
    """``V[:K]`` made periodic: ``V[K] = V[0] H`` (``H`` block diagonal over the clusters of
    ``index``, the holonomy of the continuation); each sample times ``expm(-G tau)``, ``G`` the
    real logarithm of ``H``'s cluster block, ``tau = t / T`` (batched through the blocks'
    eigen-decompositions: ``expm(-G tau) = S diag(h^-tau) S^-1``; a defective block, e.g. a Jordan
    block, by its own :func:`scipy.linalg.expm`).  Raises :class:`ModalBasisError` when ``V[0]`` is
    singular (no basis)."""
    K = V.shape[0] - 1
    try:
        H = np.linalg.solve(V[0], V[K])
    except np.linalg.LinAlgError:
        raise ModalBasisError("the frozen-modal basis at t = 0 is singular") from None
    if not np.all(np.isfinite(H)):
        raise ModalBasisError("the holonomy of the frozen-modal basis is not finite")
    decomp = {size: (idx, _block_log(H[idx[:, :, None], idx[:, None, :]])) for size, idx in index.items()}
    for k in range(K):
        blocks = {}
        for size, (idx, (h, S, Sinv, logs)) in decomp.items():
            E = np.einsum("mij,mj,mjl->mil", S, np.exp(-tau[k] * np.log(h.astype(complex))), Sinv).real
            for c, G in logs.items():
                E[c] = scipy.linalg.expm(-tau[k] * G)
            blocks[size] = (idx, E)
        V[k] = _block_right(V[k], blocks)
    return V[:K]


def _eig_basis(Pb: np.ndarray, times: np.ndarray, period: float) -> tuple:
    """Basis samples ``V`` (``(K, n, n)``) and cluster bounds from a full eigen-decomposition per sample.

    Clusters by :func:`_cluster_bounds`; each cluster's real basis continued by discrete parallel
    transport, the holonomy removed (see the module notes).
    """
    K, n = Pb.shape[0], Pb.shape[1]
    lams = np.empty((K, n), dtype=complex)
    Ws = np.empty((K, n, n), dtype=complex)
    for k in range(K):
        lam, W = np.linalg.eig(Pb[k])
        order = np.lexsort((lam.imag, np.abs(lam)))  # by modulus, conjugates adjacent
        lams[k], Ws[k] = lam[order], W[:, order]
    # clusters: runs of the sorted moduli separated from the next by a gap over the whole
    # period (then each cluster's invariant subspace is a smooth function of t)
    bounds = _cluster_bounds(np.abs(lams), 2.0 * np.pi / period)
    Rs = _real_columns(lams, Ws, bounds)
    # clusters grouped by size: their small blocks are inverted / exponentiated in batches
    index = _size_groups(bounds)
    V = np.empty((K + 1, n, n))
    V[0] = Rs[0]
    for k in range(1, K + 1):
        # discrete parallel transport: each cluster's new basis has unit projection on the
        # previous left basis (rows of V_{k-1}^-1 belonging to the cluster)
        Rk = Rs[k % K]
        proj_all = np.linalg.solve(V[k - 1], Rk)
        blockinv = np.zeros((n, n))
        for size, idx in index.items():
            proj = proj_all[idx[:, :, None], idx[:, None, :]]  # (clusters, size, size)
            inv, growth = _batched_inverse(proj)
            if not np.all(growth <= MAX_CONDITION):
                raise ModalBasisError("a frozen invariant subspace turns by ~90 degrees between two samples "
                                      "(too few samples)")
            blockinv[idx[:, :, None], idx[:, None, :]] = inv
        V[k] = Rk @ blockinv
    return _remove_holonomy(V, index, times / period), bounds


#: Newton continuation of the first frame (:func:`_continued_basis`): at most this many first-order
#: corrections per sample, until the largest is <= ``CONTINUATION_TOL`` (each squares the
#: previous one: 1e-2 leaves ~1e-4, which the second frame's first-order step removes; measured on
#: the 32-element link, 144 steps: multipliers within 1.2e-10 of those with 1e-4, 3.0 instead of
#: 3.6 steps per sample); a first correction above ``MAX_CONTINUATION_STEP`` (the
#: basis turned too far between two samples for the predictor) refuses.
CONTINUATION_ITERATIONS = 6
CONTINUATION_TOL = 1e-2
MAX_CONTINUATION_STEP = 10.0


def _continued_basis(Pb: np.ndarray, times: np.ndarray, period: float) -> tuple:
    """Basis samples and cluster bounds of a first frame by Newton continuation from one ``eig``.

    A full ``eig`` at ``t = 0`` (clusters: the finest the rule of :func:`_cluster_bounds` allows
    there); at each next sample the previous basis is corrected by first-order steps ``V <- V (I + X)``, ``X`` from :func:`_first_order` of ``V^-1 P_k V``, until
    ``max |X| <= CONTINUATION_TOL`` (quadratic convergence: the invariant subspaces of every
    cluster to ~1e-4, the rest left to the next frame).  A solve and two products per step instead of an ``eig`` (measured at
    516 states: 0.21 s per ``eig``, 7 ms per product, 17 ms per solve).  The cluster blocks of the
    projection ``C = V_{k-1}^-1 V_k`` are then reset to the identity, a discrete parallel transport
    as in :func:`_eig_basis` (without the reset, the second-order products of a large first
    correction left a non-smooth in-cluster scaling that merged the hub clusters of the second
    frame of the 2-element link at 4 pi; a linear predictor
    ``2 V_{k-1} - V_{k-2}`` was tried: nothing corrects its in-cluster part, which then drifts
    like a marginally stable recursion, and the second frame's coupling grew 100x); its
    holonomy is removed as in :func:`_eig_basis`.  The clusters are then checked against the block
    eigenvalues over the whole period and merged (the sweep redone) where the rule breaks.
    Raises :class:`_PerturbationFailed` when a sample does not converge.
    """
    K, n = Pb.shape[0], Pb.shape[1]
    omega = 2.0 * np.pi / period
    lam, W = np.linalg.eig(Pb[0])
    order = np.lexsort((lam.imag, np.abs(lam)))
    lam, W = lam[order], W[:, order]
    bounds = _cluster_bounds(np.abs(lam)[None, :], omega)
    start = _real_columns(lam[None], W[None], bounds)[0]
    for _ in range(4):
        index = _size_groups(bounds)
        labels = np.repeat(np.arange(len(bounds)), [b - a for a, b in bounds])
        mus = np.empty((K, n), dtype=complex)
        V = np.empty((K + 1, n, n))
        V[0] = start
        for k in range(1, K + 1):
            Vk, C = V[k - 1], np.eye(n)  # Vk = V[k - 1] C
            for it in range(CONTINUATION_ITERATIONS):
                X, mu = _first_order(np.linalg.solve(Vk, Pb[k % K] @ Vk), index, labels)
                step = float(np.abs(X).max())
                if it == 0 and not step <= MAX_CONTINUATION_STEP:
                    raise _PerturbationFailed(f"the basis turns by {step:.1e} between two samples")
                Vk = Vk + Vk @ X
                if step > CONTINUATION_TOL ** 2:  # C's cluster blocks change at second order only
                    C = C + C @ X
                if step <= CONTINUATION_TOL:
                    break
            else:
                raise _PerturbationFailed(f"Newton continuation stalls at {step:.1e}")
            # exact unit projection on the previous basis: the cluster blocks of C (I + second-order
            # products of the corrections, not small after a large first step) back to the identity
            blocks = {}
            for size, idx in index.items():
                try:
                    blocks[size] = (idx, np.linalg.inv(C[idx[:, :, None], idx[:, None, :]]))
                except np.linalg.LinAlgError:
                    raise _PerturbationFailed("a cluster's projection on the previous basis is singular") from None
            V[k], mus[k % K] = _block_right(Vk, blocks), mu
        merged = _merge_cuts(mus, bounds, omega)
        if merged == bounds:
            return _remove_holonomy(V, index, times / period), bounds
        bounds = merged
    raise _PerturbationFailed("the clusters did not settle")


def _condition(A: np.ndarray) -> float:
    """1-norm condition number estimate of ``A`` (LAPACK ``gecon`` on its LU factors: ``O(n^3 / 3)``
    instead of an SVD; within a factor ``n`` of the 2-norm condition number)."""
    lu, _ = scipy.linalg.lu_factor(A, check_finite=False)
    rcond, info = scipy.linalg.lapack.dgecon(lu, float(np.abs(A).sum(axis=0).max()), norm="1")
    return float(1.0 / rcond) if info == 0 and rcond > 0 else math.inf


def _samples_of(P: Any, K: int) -> Optional[np.ndarray]:
    """``P_hat`` of a frozen-modal frame ``P`` at its own ``K`` sample times, from the samples it was
    built from (no new evaluation of the model's ``P``, no trigonometric evaluation): at
    ``t_k = k T / K`` the interpolant ``V`` is the sample itself and ``V'`` its spectral derivative
    (the Nyquist term's derivative vanishes there), so this equals ``P.evaluate(t_k)``; ``K`` may
    divide ``P``'s sample count (every ``N / K``-th sample).  None when ``P`` is no frame or was
    sampled otherwise.  Used once (the cache is then dropped)."""
    cache = getattr(P, "_sample_cache", None) if isinstance(P, FrozenModalSystem) else None
    if cache is None or cache[1].shape[0] % K:
        return None
    Pb, V = cache
    P._sample_cache = None
    N = V.shape[0]
    k = np.arange(N // 2 + 1) * (2.0 * np.pi / P.period)
    k[-1] = 0.0
    stride = N // K  # every stride-th of the parent's N samples: t_j = j T / K
    Vt = np.fft.irfft(np.fft.rfft(V, axis=0) * (1j * k)[:, None, None], n=N, axis=0)[::stride]
    return np.linalg.solve(V[::stride], Pb[::stride] @ V[::stride] - Vt)


def _parent_bounds(P: Any) -> Optional[list]:
    """Cluster bounds of ``P`` when it is itself a frozen-modal frame (nearly block diagonal), else None."""
    if not isinstance(P, FrozenModalSystem):
        return None
    cuts = np.cumsum(P.clusters)[:-1].tolist()
    return list(zip([0] + cuts, cuts + [P.n]))


def _transformed(P: np.ndarray, V: np.ndarray, Vt: np.ndarray) -> np.ndarray:
    """``V^-1 (P V - V')`` for stacks of matrices: the system matrix in the basis ``V``
    (one product and one LU solve per time)."""
    X = P @ V
    X -= Vt
    return np.linalg.solve(V, X)


class FrozenModalSystem:
    """``P_hat(t) = V^-1 (P V - V')`` for a smooth periodic frozen-eigenvector basis ``V(t)``.

    Same Floquet multipliers as ``P`` (see the module notes); a periodic
    matrix for :func:`stability.floquet` (``period``, ``evaluate``,
    ``__call__``, ``trace_integral``).

    Parameters
    ----------
    P : periodic matrix
        Real ``P(t)`` with ``.period`` and ``evaluate(times)`` (or callable).
    samples : int, optional
        Eigenvector samples per period (even, >= 4); default :data:`DEFAULT_MODAL_SAMPLES`.
    period : float, optional
        When ``P`` has no ``.period``.
    method : {"auto", "eig", "perturbation"}
        How the basis samples are built (:data:`BASIS_METHODS`).

    Attributes
    ----------
    clusters : tuple of int
        Sizes of the clusters of frozen eigenvalues (the diagonal blocks of ``P_hat``), in order.
    method : str
        The construction actually used: ``"eig"`` or ``"perturbation"``.
    condition : float
        Largest 1-norm condition number estimate of the sampled basis (balanced coordinates).

    Raises
    ------
    ModalBasisError
        If the eigenvector continuation does not close into a real periodic basis.
    ValueError
        For an unknown ``method`` or bad ``samples``.
    """

    def __init__(self, P: Any, samples: Optional[int] = None, period: Optional[float] = None,
                 method: str = "auto") -> None:
        if method not in BASIS_METHODS:
            raise ValueError(f"method must be one of {BASIS_METHODS}, got {method!r}")
        self.original = P
        self._trace: Optional[float] = None
        self._wrapped = PeriodicMatrixFunction(P, period)
        self.period = self._wrapped.period
        self.n = self._wrapped.n
        K = int(samples if samples is not None else DEFAULT_MODAL_SAMPLES)
        if K < 4 or K % 2:
            raise ValueError(f"samples must be an even integer >= 4, got {samples!r}")
        self.samples = K
        times = np.arange(K) * (self.period / K)
        Ps = _samples_of(P, K)
        if Ps is None:
            Ps = self._wrapped.evaluate(times)
        # one diagonal scaling for all samples (LAPACK's balancing of mean |P|): the eigenvector
        # matrices mix metres, radians and their rates; balanced they are well conditioned
        _, (scale, _) = scipy.linalg.matrix_balance(np.abs(Ps).mean(axis=0), permute=False, separate=True)
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
        Pb = Ps * (scale[None, :] / scale[:, None])
        self.method = "eig"
        V = bounds = None
        parent = _parent_bounds(P)
        if method != "eig":
            try:
                if parent is not None:
                    V, bounds = _perturbed_basis(Pb, parent, 2.0 * np.pi / self.period)
                else:
                    V, bounds = _continued_basis(Pb, times, self.period)
                self.method = "perturbation"
            except (_PerturbationFailed, ModalBasisError) as exc:
                if method == "perturbation":
                    raise ModalBasisError(f"no first-order frozen-modal basis ({exc})") from None
                logger.info("first-order basis refused (%s): full eigen-decompositions", exc)
        if V is None:
            V, bounds = _eig_basis(Pb, times, self.period)
        self.clusters = tuple(int(b - a) for a, b in bounds)
        cond = max(_condition(V[k]) for k in range(0, K, max(1, K // 4)))
        if not cond <= MAX_CONDITION:
            raise ModalBasisError(f"the frozen eigenvector basis is nearly singular (condition {cond:.1e})")
        self.scale = scale
        self.condition = cond
        self._coef = _trig_coefficients(V)
        # what a frame nested in this one needs at the same sample times (see _samples_of)
        self._sample_cache = (Pb, V)
        self.basis_samples = V * scale[None, :, None]  # in the original (unbalanced) coordinates

    def with_system(self, P: Any) -> "FrozenModalSystem":
        """The same basis ``V(t)`` applied to another periodic matrix of the same size and period.

        Exact for any ``P`` (the multipliers never depend on the basis); efficient when ``P``'s
        stiff part is close to this one's, e.g. the same linearisation with other PD gains
        (a tuning loop then computes the eigenvector samples once).
        """
        other = object.__new__(FrozenModalSystem)
        other.__dict__.update(self.__dict__)
        other.original = P
        other._trace = None
        other._sample_cache = None  # the samples of *this* P: never a nested frame's input
        other._wrapped = PeriodicMatrixFunction(P, self.period)
        if other._wrapped.n != self.n or abs(other._wrapped.period - self.period) > 1e-12 * self.period:
            raise ValueError("with_system needs a periodic matrix of the same size and period")
        return other

    def _table(self) -> np.ndarray:
        """The real coefficient table of ``V`` (:func:`_trig_table`), formed once (shared by
        :meth:`with_system` copies: same basis)."""
        table = self.__dict__.get("_trig")
        if table is None or table[0] is not self._coef:
            table = (self._coef, _trig_table(self._coef))
            self._trig = table
        return table[1]

    def basis(self, times: np.ndarray, derivative: bool = False) -> np.ndarray:
        """``V(t)`` (or ``V'(t)``) in the balanced coordinates ``D^-1 x``, shape ``(m, n, n)``."""
        t = np.atleast_1d(np.asarray(times, dtype=float))
        rows = _trig_rows(self._coef.shape[0], self.period, t, derivative)
        return (rows @ self._table()).reshape((t.size, self.n, self.n))

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        """``P_hat(t)`` at ``times``, shape ``(m, n, n)``.

        ``P_hat = V^-1 (D^-1 P D V - V')`` as one product and one LU solve per time, with the
        balancing ``D`` applied in place and ``V, V'`` from :meth:`basis` (real arithmetic).
        (Reading the coefficient table once for both would save < 1 % of a propagation; going
        through :meth:`basis` keeps the derivative replaceable, as the tests that drop it do.)"""
        t = np.atleast_1d(np.asarray(times, dtype=float))
        P = self._wrapped.evaluate(t)
        cached = self.__dict__.get("_ratio")
        if cached is None or cached[0] is not self.scale:
            cached = self._ratio = (self.scale, self.scale[None, :] / self.scale[:, None])
        if isinstance(self.original, FrozenModalSystem):
            P *= cached[1]  # a fresh array from the inner frame's solve: balanced in place
        else:
            P = P * cached[1]  # a user's P(t) may hand out its own arrays: never written to
        return _transformed(P, self.basis(t), self.basis(t, derivative=True))

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([float(t)]))[0]

    def _collapsed_table(self) -> tuple:
        """``(K, table)``: the real trigonometric table (:func:`_trig_table`, ``K`` harmonics
        ``0 .. K - 1``) of the composite basis ``U`` of this frame and every frame it is nested in,
        in the balanced coordinates of the innermost one: ``U = V1`` for a first frame, ``U = U_in D V``
        for a frame with scaling ``D`` and basis ``V`` nested in one with composite basis ``U_in``.

        Exact up to rounding: ``U_in`` and ``V`` are trigonometric polynomials of degree ``d_in`` and
        ``d`` whose Nyquist terms are pure cosines (interpolants of real samples), so ``U_in D V`` is one
        of degree ``d_in + d`` whose top harmonic is a pure cosine too; its ``N = 2 (d_in + d)``
        equispaced samples (``K1 + K2`` for two frames) determine it uniquely, and the interpolant of
        those samples is ``U`` itself, hence ``U'`` of the table is exactly ``U_in' D V + U_in D V'``.
        Rounding: each sample carries ``~ n eps |U_in| |D| |V|`` (the product), the FFT adds
        ``O(eps log N)`` relative.  Formed once (``N`` products of ``n x n``) and cached; shared by
        :meth:`with_system` copies made after it was formed (the bases, not ``P``)."""
        if not isinstance(self.original, FrozenModalSystem):
            return self._coef.shape[0], self._table()
        K_in, table_in = self.original._collapsed_table()
        cached = self.__dict__.get("_collapsed")
        if cached is not None and cached[0] is self._coef and cached[1] is table_in:
            return cached[2], cached[3]
        K_self = self._coef.shape[0]
        N = 2 * ((K_in - 1) + (K_self - 1))
        times = np.arange(N) * (self.period / N)
        U = np.empty((N, self.n, self.n))
        own = self._table()
        for lo in range(0, N, 8):  # a few samples at a time: three (8, n, n) temporaries
            t = times[lo:lo + 8]
            inner = (_trig_rows(K_in, self.period, t, False) @ table_in).reshape(t.size, self.n, self.n)
            inner *= self.scale[None, None, :]
            mine = (_trig_rows(K_self, self.period, t, False) @ own).reshape(t.size, self.n, self.n)
            np.matmul(inner, mine, out=U[lo:lo + 8])
        coef = _trig_coefficients(U)
        del U
        K = coef.shape[0]
        table = _trig_table(coef)
        self._collapsed = (self._coef, table_in, K, table)
        return K, table

    def collapsed(self) -> "FrozenModalSystem | CollapsedModalSystem":
        """The same ``P_hat`` evaluated in one composite basis (:class:`CollapsedModalSystem`): for
        nested frames one product and one LU solve per time instead of one per frame.  A first frame
        (not nested) is returned as it is."""
        if not isinstance(self.original, FrozenModalSystem):
            return self
        return CollapsedModalSystem(self)

    def trace_integral(self) -> float:
        """``int_0^T tr P dt`` of the *original* ``P`` (= that of ``P_hat`` for a periodic ``V``;
        Liouville's check of the result then also checks the periodicity of ``V``)."""
        if self._trace is None:
            from stability.floquet import _trace_integral

            # the closed form when the original has one, else floquet's nested trapezoidal rule
            # (64 .. stability.floquet.TRACE_POINTS evaluations, until converged)
            self._trace = _trace_integral(self.original, self._wrapped, self.period)
        return self._trace

    def to_original(self, monodromy: np.ndarray) -> np.ndarray:
        """``Phi(T) = V(0) Phi_hat(T) V(0)^-1`` in the original coordinates of ``P``."""
        V0 = self.basis_samples[0]
        return V0 @ np.linalg.solve(V0.T, np.asarray(monodromy).T).T


class CollapsedModalSystem:
    """``P_hat`` of nested frozen-modal frames in one composite basis: ``P_hat = U^-1 (P_b U - U')``.

    For frames ``P_hat_1 = V1^-1 (D1^-1 P D1 V1 - V1')`` and ``P_hat_2 = V2^-1 (D2^-1 P_hat_1 D2 V2 -
    V2')``: with ``U = V1 D2 V2`` and ``P_b = D1^-1 P D1``, ``P_hat_1 D2 V2 - D2 V2' = V1^-1 (P_b U -
    U')`` since ``U' = V1' D2 V2 + V1 D2 V2'``, so ``P_hat_2 = U^-1 (P_b U - U')`` exactly (the
    same for deeper nesting).  ``U`` and ``U'`` come from one trigonometric table
    (:meth:`FrozenModalSystem._collapsed_table`), so each time costs one product and one LU solve
    instead of one per frame.  Equal to ``frame.evaluate`` up to rounding (both are backward
    stable for the same exact matrix: forward difference ``<~ cond(U) n eps |P_hat|``).

    A periodic matrix for :func:`stability.floquet` (``period``, ``n``, ``evaluate``, ``__call__``,
    ``trace_integral``); ``clusters`` are the outermost frame's.  ``frame`` is the nested
    :class:`FrozenModalSystem` it evaluates (its ``to_original`` chain maps monodromies back).
    """

    def __init__(self, frame: FrozenModalSystem) -> None:
        inner = frame
        while isinstance(inner.original, FrozenModalSystem):
            inner = inner.original
        self.frame = frame
        self.original = inner.original
        self._wrapped = inner._wrapped
        self.period = frame.period
        self.n = frame.n
        self.scale = inner.scale
        self.clusters = frame.clusters
        self._K, self._table = frame._collapsed_table()
        self._ratio = self.scale[None, :] / self.scale[:, None]

    def basis(self, times: np.ndarray, derivative: bool = False) -> np.ndarray:
        """``U(t)`` (or ``U'(t)``) in the innermost frame's balanced coordinates, shape ``(m, n, n)``."""
        t = np.atleast_1d(np.asarray(times, dtype=float))
        rows = _trig_rows(self._K, self.period, t, derivative)
        return (rows @ self._table).reshape((t.size, self.n, self.n))

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        """``P_hat(t)`` at ``times``, shape ``(m, n, n)``: one product and one LU solve per time."""
        t = np.atleast_1d(np.asarray(times, dtype=float))
        P = self._wrapped.evaluate(t) * self._ratio  # a user's P(t) may hand out its own arrays: a copy
        return _transformed(P, self.basis(t), self.basis(t, derivative=True))

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([float(t)]))[0]

    def trace_integral(self) -> float:
        """That of the nested frame (= ``int_0^T tr P dt`` of the base ``P``)."""
        return self.frame.trace_integral()


#: Range of ``d2 / d1`` (change of the extrapolated multiplier over two doublings / over the last
#: one) in which the last change ``d1`` is trusted as the estimate (:func:`_extrapolated`):
#: ``d2 = d1 + d0`` with ``d0 / d1`` = 4 (order 2) .. 32 (order 5).
TRUSTED_RATIOS = (5.0, 33.0)


def _extrapolated(system: "FrozenModalSystem", fine: Any, options: dict) -> Any:
    """Richardson-extrapolated result from ``fine`` (``N`` steps) and two more solves (``N/2``, ``N/4``).

    Maths: the exponential midpoint rule is symmetric, so its monodromy matrix
    has an error expansion in even powers, ``Phi_N = Phi + C h^2 + O(h^4)``;
    ``R_N = (4 Phi_N - Phi_{N/2}) / 3`` is then 4th order.  The error estimate
    of each multiplier of ``R_N`` is its change ``d1`` from ``R_{N/2}`` *undivided*
    (the asymptotic ``/ 15`` is not claimed), which bounds the error whenever the
    extrapolated values converge at least linearly.  That premise is checked
    (ratio 2, :data:`TRUSTED_RATIOS`): with ``d2`` the change of ``R_N`` from
    ``R_{N/4}`` (one more solve, ``N/8``), ``d1`` is used only if ``d2 / d1`` lies
    in ``[5, 33]`` (the previous change 4..32 times the last: order 2..5 seen over
    two doublings); otherwise the estimate is ``max(d1, d2)``.  Measured on the
    2-element single link (Table 3 gains, against the same linearisation at 2048
    steps): one frame at 8 pi, 256 steps, ``d1 = 4.7e-8`` for a true error 1.3e-6
    (``d2 / d1 = 142``: an accidental agreement of ``R_128`` and ``R_256``), and at
    32 steps ``d1 = 1.4e-4`` for 6.3e-4; with the rule every case of 32..512 steps,
    one and two frames, 2 pi and 8 pi, has estimate >= error.  With ``N`` not
    divisible by 8 the estimate is ``max(d1, |R_N - Phi_N|)`` (the 2nd-order
    change of the raw solve).  The ratio-3 path keeps ``d1`` (no third level from
    the companions; measured there estimate / error >= 70 on the same cases).

    Limitation (measured, ``benchmarks/modal_estimate_check.py``, frames with the 5 %
    cluster-gap rule): on the 8-element single link (2 pi, Table 3 gains, against the same frames at 2592 steps, whose
    difference from 1296 steps is 1.8e-9) the estimate does *not* bound the error of
    one pair of moduli (0.999875) at several step counts: 144 steps estimate 2.0e-7,
    error 1.6e-6; also 72, 135, 153, 360 (ratio 3) and 160, 256 (ratio 2).  The raw
    midpoint error of that pair is erratic in ``N`` (about 1.6e-6 at 72, 144 and 288
    steps, 5e-9 at 576, 6e-10 at 864), the same on grids shifted by ``h`` and ``2 h``
    (the ``N / 3`` rules from every third factor at the three offsets agree to 1e-11),
    i.e. not an ``h^2`` expansion: consistent with a step-size resonance of the stiff
    frozen frequencies (``Delta omega h`` near a multiple of ``2 pi``), which every
    nested coarser level (``N / 2``, ``N / 3``, ``N / 9``) shares, so no estimate from
    nested solves can see it.  At 16 elements the estimates bound the errors at 72-648
    steps (against 1296 steps, whose own estimate is 4e-7).
    ``options["accuracy"] = "dominant"``: the estimate is the largest ``changes`` entry over
    :func:`stability.floquet.dominant_mask`'s multipliers (the spectral radius and those whose
    error interval, widened ``DOMINANT_SAFETY`` = 10 times, reaches its one); the per-multiplier
    ``changes`` (``reliable_digits``, the verdict band) are the same as with ``"moduli"``.
    The frozen-modal frame is what makes the expansion hold at a few dozen
    steps: there the stiff blocks are nearly exact already and the error is the
    smooth ``h^2`` error of the slow modes (measured ratio 3.9-4.0 per doubling
    on the single link).
    """
    from stability.floquet import (_estimate, _liouville, _phase_changes, _select_changes, _spectrum,
                                   _verdict, floquet)

    N = int(fine.n_steps)
    if len(fine.companion_monodromies) == 2:
        # N / 3 and N / 9 from the N-step factors (stability.floquet: expm(3 h P) = expm(h P)^3):
        # ratio 3, R = (9 Phi_N - Phi_{N/3}) / 8, no further exponentials
        r2, (mid, coarse) = 9.0, fine.companion_monodromies
        extra_evaluations, extra_elapsed = 0, 0.0
    else:
        opts = dict(options, error_estimate=False)
        half = floquet(system, **dict(opts, n_steps=N // 2))
        quarter = floquet(system, **dict(opts, n_steps=N // 4))
        r2, mid, coarse = 4.0, half.monodromy, quarter.monodromy
        extra_evaluations, extra_elapsed = half.n_evaluations + quarter.n_evaluations, half.elapsed + quarter.elapsed
    R1 = (r2 * fine.monodromy - mid) / (r2 - 1.0)
    R0 = (r2 * mid - coarse) / (r2 - 1.0)
    check = None  # the matrix whose change from R1 is d2 (see the docstring)
    if r2 == 4.0 and N % 8 == 0:
        eighth = floquet(system, **dict(opts, n_steps=N // 8))
        extra_evaluations, extra_elapsed = extra_evaluations + eighth.n_evaluations, extra_elapsed + eighth.elapsed
        check = (r2 * coarse - eighth.monodromy) / (r2 - 1.0)
    elif r2 == 4.0:
        check = fine.monodromy
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        spec, prev = _spectrum(R1), _spectrum(R0)
        accuracy = options.get("accuracy", "moduli")
        changes = _select_changes(spec, prev, accuracy)
        if check is not None:
            d2 = _select_changes(spec, _spectrum(check), accuracy)
            lo, hi = TRUSTED_RATIOS
            trusted = (d2 >= lo * changes) & (d2 <= hi * changes) if N % 8 == 0 else np.zeros(len(changes), bool)
            changes = np.where(trusted, changes, np.maximum(changes, d2))
        est = _estimate(changes, spec, 1.0, accuracy)  # "dominant": over dominant_mask's multipliers
        phase = _estimate(_phase_changes(spec, prev), spec, 1.0)
        rho = float(math.exp(spec.log_moduli[0]))
        moduli = np.exp(spec.log_moduli)
        noise_digits = np.clip(np.log10(moduli / fine.noise_floor), 0.0, 16.0)
        digits = np.minimum(noise_digits, np.clip(-np.log10(np.maximum(changes, 1e-16)), 0.0, 16.0))
    reliable_all = bool((moduli > 100.0 * fine.noise_floor).all())
    mult_liouville = _liouville(float(spec.log_moduli.sum()), fine.trace_integral) if reliable_all else math.nan
    liouville = mult_liouville if fine.liouville_source == "multipliers" and reliable_all else fine.liouville_residual
    # the verdict band: stable only if every modulus plus its estimated error stays below 1, i.e.
    # tol = max_i |rho_i| (1 + e_i) - rho (a strongly damped stiff multiplier of modulus 1e-4 may carry
    # a large relative estimate without coming near |rho| = 1)
    keep = spec.log_moduli >= spec.log_moduli[0] + math.log(1e-6)
    upper = float(np.max(np.where(np.isfinite(changes[keep]), moduli[keep] * (1.0 + changes[keep]), np.inf)))
    tol = max(float(options.get("stability_tol", 1e-8)), upper - rho)
    return replace(fine, multipliers=spec.values, log_moduli=spec.log_moduli, monodromy=R1, spectral_radius=rho,
                   verdict=_verdict(rho, tol), stability_tolerance=tol, liouville_residual=liouville,
                   multiplier_liouville_residual=mult_liouville, error_estimate=est, reliable_digits=digits,
                   n_evaluations=fine.n_evaluations + extra_evaluations,
                   elapsed=fine.elapsed + extra_elapsed, phase_error_estimate=phase)


def _check_steps(N: int, by_nine: bool) -> int:
    """Step count ``M >= 9 N / 8`` of the non-nested check solve of :func:`_checked`: the next multiple
    of 9 (``by_nine``: a system larger than ``SMALL_N``, ratio 3 from the ``M``-step factors) or of 8
    (ratio 2 with ``M / 2``, ``M / 4``, ``M / 8``); ``9 N / 8`` itself when 72 divides ``N``."""
    return 9 * math.ceil(N / 8) if by_nine else 8 * math.ceil(9 * N / 64)


def _fixed_extrapolated(system: "FrozenModalSystem", N: int, options: dict) -> Any:
    """The extrapolated solve of :func:`modal_floquet` at a fixed ``N`` (ratio 3 when it can, else 2)."""
    from stability.floquet import SMALL_N, floquet

    opts = dict(options, n_steps=N)
    if N % 9 == 0 and system.n > SMALL_N:
        fine = floquet(system, **dict(opts, error_estimate=True))
        if len(fine.companion_monodromies) == 2:
            return _extrapolated(system, fine, opts)
    return _extrapolated(system, floquet(system, **dict(opts, error_estimate=False)), opts)


def _checked(system: "FrozenModalSystem", res: Any, options: dict) -> Any:
    """``res`` (extrapolated, ``N`` steps) with its estimate raised by a non-nested check solve.

    The nested estimate of :func:`_extrapolated` compares ``N`` with ``N / 2``, ``N / 3``, ...: an
    error that repeats on every grid of the family (measured on the single link: the spectral
    radius of the extrapolated frozen-modal solve at 16 elements is 1 - 3.064e-7 at 72, 144 and
    1152 steps and 1 - 3.092e-7 at 216, with nested estimates of ~3e-12) is invisible to it.  The
    check solves again, extrapolated, with ``M ~ 9 N / 8`` steps (:func:`_check_steps`: not in
    ``N``'s family), and the estimate of each multiplier becomes the larger of its nested estimate
    and its relative change to the ``M``-step solve (sorted moduli, or multipliers with
    ``accuracy="multipliers"``) plus the ``M`` solve's own nested estimate (``|e_N| <= |R_N - R_M|
    + |e_M|``); ``error_estimate`` is their maximum over what ``accuracy`` covers,
    ``reliable_digits`` and the verdict band follow.  The ``M`` solve's cost is counted.
    The premise: ``M``'s nested estimate bounds its error (``M`` is not in a family that shares
    ``N``'s error); if both are off alike the difference can be small - a heuristic, measured in
    ``benchmarks/modal_estimate_check.py --check``.
    """
    from stability.floquet import SMALL_N, _estimate, _select_changes, _Spectrum, _verdict

    M = _check_steps(int(res.n_steps), system.n > SMALL_N)
    other = _fixed_extrapolated(system, M, options)
    accuracy = options.get("accuracy", "moduli")
    a = _Spectrum(np.asarray(res.multipliers), np.asarray(res.log_moduli))
    b = _Spectrum(np.asarray(other.multipliers), np.asarray(other.log_moduli))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        d = _select_changes(a, b, accuracy)
        # per multiplier, capped at 1e-16: the nested estimates of both solves
        nested = 10.0 ** -np.asarray(res.reliable_digits, float)
        nested_m = 10.0 ** -np.asarray(other.reliable_digits, float)
        # triangle inequality: |e_N| <= |R_N - R_M| + |e_M|, e_M by the M solve's own estimate
        changes = np.maximum(nested, d + nested_m)
        est = max(float(res.error_estimate), _estimate(changes, a, 1.0, accuracy))
        digits = np.minimum(res.reliable_digits, np.clip(-np.log10(np.maximum(d, 1e-16)), 0.0, 16.0))
        moduli = np.exp(a.log_moduli)
        rho = float(res.spectral_radius)
        keep = a.log_moduli >= a.log_moduli[0] + math.log(1e-6)
        upper = float(np.max(np.where(np.isfinite(changes[keep]), moduli[keep] * (1.0 + changes[keep]), np.inf)))
    tol = max(float(res.stability_tolerance), upper - rho)
    logger.debug("non-nested check at %d steps (N = %d): estimate %.2e -> %.2e", M, res.n_steps,
                 res.error_estimate, est)
    return replace(res, error_estimate=est, reliable_digits=digits, stability_tolerance=tol,
                   verdict=_verdict(rho, tol), n_evaluations=res.n_evaluations + other.n_evaluations,
                   elapsed=res.elapsed + other.elapsed)


#: First step count of the adaptive extrapolated solve (``modal_floquet(extrapolate=True,
#: n_steps=None)``): divisible by 9 (ratio 3, ``N / 3`` and ``N / 9`` from the ``N`` factors, on
#: systems larger than ``stability.floquet.SMALL_N``) and by 8 (ratio 2 with the premise check on
#: small ones).
ADAPTIVE_START_STEPS = 72
#: Each refinement multiplies the step count by the smallest of these ratios that the order-4
#: model of the estimate (``est ~ N^-4``) says reaches ``rtol`` with a margin of ``1.2`` in ``N``
#: (the largest when none does): the counts stay divisible by 72, and a pass never grows the work
#: more than 4-fold on an extrapolation of the model.
ADAPTIVE_RATIOS = (2, 3, 4)
ADAPTIVE_MARGIN = 1.2


def _adaptive_extrapolated(system: "FrozenModalSystem", options: dict, check: bool = False) -> Any:
    """:func:`_extrapolated` at ``N = ADAPTIVE_START_STEPS, ...`` until its estimate is ``<= rtol``.

    The step count is chosen from the accuracy reached, not fixed: each pass is one fixed-``N``
    extrapolated solve (its estimate as :func:`_extrapolated` certifies it); if the estimate
    ``e`` misses ``rtol`` the next count is ``N r``, ``r`` the smallest of
    :data:`ADAPTIVE_RATIOS` with ``r >= 1.2 (e / rtol)^(1/4)`` (the estimate falls like
    ``N^-4`` in the asymptotic range; the largest if none).  Every pass
    counts in ``n_evaluations`` and ``elapsed``.  Raises :class:`stability.FloquetError` when
    the next count would exceed ``max_steps`` (the estimate reached is in the message).
    The premise of any such choice is that the estimate bounds the error at the count where
    it stops: see the limitation measured in :func:`_extrapolated`.  ``check``: every pass adds
    the non-nested check solve of :func:`_checked` (``9 N / 8`` steps) to its estimate.
    """
    from stability.floquet import MAX_STEPS, FloquetError

    rtol = float(options.get("rtol", 1e-9))
    if not (math.isfinite(rtol) and rtol > 0):
        raise ValueError(f"rtol must be finite and > 0, got {rtol!r}")
    max_steps = int(options.get("max_steps", MAX_STEPS))
    N = ADAPTIVE_START_STEPS
    evaluations, elapsed = 0, 0.0
    while True:
        res = _fixed_extrapolated(system, N, options)  # N stays a multiple of 72: ratio 3 on large systems
        if check:
            res = _checked(system, res, dict(options, n_steps=N))
        evaluations, elapsed = evaluations + res.n_evaluations, elapsed + res.elapsed
        est = float(res.error_estimate)
        if est <= rtol:
            logger.debug("adaptive extrapolated solve: %d steps, estimate %.2e <= rtol %.1e", N, est, rtol)
            return replace(res, n_evaluations=evaluations, elapsed=elapsed)
        need = ADAPTIVE_MARGIN * (est / rtol) ** 0.25 if math.isfinite(est) else math.inf
        r = next((q for q in ADAPTIVE_RATIOS if need <= q), ADAPTIVE_RATIOS[-1])
        if N * r > max_steps:
            raise FloquetError(f"frozen-modal extrapolated solve: estimate {est:.1e} > rtol {rtol:.1e} at {N} "
                               f"steps, and {N * r} steps exceed max_steps = {max_steps}")
        N *= r


#: Frozen-modal frames stacked by :func:`modal_system`: the second frame is the frozen-modal
#: basis of the first frame's ``P_hat``, which removes the first-order coupling ``-V^-1 V'``
#: between the modes (a superadiabatic iteration).  Measured on the 8-element single link at
#: 6 pi / 8 pi (extrapolated, 128 steps): hub multiplier 2.1e-6 / ~2e-6 off with one frame
#: (and no longer converging cleanly), 7e-8 / 3e-7 with two (4th order from 64 to 128 steps).
#: Not always better: on the two-link arm with gains (4 pi) 5.7e-5 with two frames against 1.4e-7
#: with one (see :func:`linearize.analysis.analyze`, which then tries one frame).
MODAL_LEVELS = 2


def modal_system(P: Any, levels: int = MODAL_LEVELS, samples: Optional[int] = None,
                 period: Optional[float] = None) -> "FrozenModalSystem":
    """``levels`` nested frozen-modal frames of ``P`` (fewer if a deeper one has no smooth basis).

    The first frame is retried with twice the samples (up to :data:`MAX_MODAL_SAMPLES`) when
    its continuation fails; raises :class:`ModalBasisError` only if it fails at all of them.
    """
    K = int(samples if samples is not None else DEFAULT_MODAL_SAMPLES)
    while True:
        try:
            system = FrozenModalSystem(P, K, period)
            break
        except ModalBasisError:
            if 2 * K > MAX_MODAL_SAMPLES:
                raise
            K *= 2
    for _ in range(int(levels) - 1):
        try:
            nested = NESTED_MODAL_SAMPLES if system.samples % NESTED_MODAL_SAMPLES == 0 else system.samples
            system = FrozenModalSystem(system, nested)
        except ModalBasisError as exc:
            logger.info("no deeper frozen-modal frame (%s)", exc)
            break
    frame = system
    while isinstance(frame, FrozenModalSystem):  # no deeper frame will read the samples: free them
        frame._sample_cache, frame = None, frame.original
    return system


def _to_base(system: Any, monodromy: np.ndarray) -> np.ndarray:
    """Map a monodromy matrix from the innermost frame back through every frame to the base ``P``."""
    while isinstance(system, FrozenModalSystem):
        monodromy = system.to_original(monodromy)
        system = system.original
    return monodromy


def _rebase(system: "FrozenModalSystem", P: Any) -> "FrozenModalSystem":
    """The same (nested) bases applied to another base ``P`` (:meth:`FrozenModalSystem.with_system`)."""
    if isinstance(system.original, FrozenModalSystem):
        return system.with_system(_rebase(system.original, P))
    return system.with_system(P)


def modal_floquet(P: Any, *, samples: Optional[int] = None, basis: Optional[FrozenModalSystem] = None,
                  extrapolate: bool = False, levels: int = MODAL_LEVELS, check: bool = False,
                  collapse: bool = True,
                  **options: Any) -> ModalFloquetResult:
    """:func:`stability.floquet` of ``P`` propagated in frozen-modal coordinates.

    Builds :class:`FrozenModalSystem`, runs :func:`stability.floquet` with ``options``
    on it and returns its result (:class:`ModalFloquetResult`, ``frame="modal"``) with the
    monodromy matrix mapped back to the coordinates of ``P``.  On :class:`ModalBasisError`
    it warns (``RuntimeWarning``) and applies the fallback policy of :data:`FALLBACK_METHOD`
    (adaptive, in ``P``'s coordinates, ``frame="model"``; ``n_steps``, ``method``,
    ``error_estimate`` and ``extrapolate`` are then ignored).  ``basis``: reuse the
    basis of another :class:`FrozenModalSystem` (:meth:`FrozenModalSystem.with_system`);
    ``levels``: nested frames (:func:`modal_system`).

    ``extrapolate=True`` (a fixed ``n_steps`` divisible by 4, ``method="magnus2"``,
    no ``small_multipliers="qr"``): the multipliers are those of the
    Richardson-extrapolated monodromy ``(4 Phi_N - Phi_{N/2}) / 3`` (4th order),
    with the error estimate from its change against ``(4 Phi_{N/2} - Phi_{N/4}) / 3``
    (see :func:`_extrapolated`); ``monodromy`` is the extrapolated matrix, and the
    verdict band is ``max_i |rho_i| (1 + e_i) - rho`` (stable only if every modulus plus
    its estimated error is below 1).  With
    ``n_steps`` divisible by 9 on a system larger than ``stability.floquet.SMALL_N``
    the ratio is 3 instead, ``(9 Phi_N - Phi_{N/3}) / 8`` against
    ``(9 Phi_{N/3} - Phi_{N/9}) / 8``, and the coarser solves come from the
    ``N``-step factors (``FloquetResult.companion_monodromies``): ``N``
    exponentials in all instead of ``1.75 N``.
    ``extrapolate=True`` with ``n_steps=None`` (``method="magnus2"``): the step count is
    chosen from the accuracy reached (:func:`_adaptive_extrapolated`): 72, then 144 or
    216, ... steps until the extrapolated estimate is ``<= rtol`` (``options["rtol"]``,
    default that of :func:`stability.floquet`, 1e-9), at most ``max_steps``.
    ``check=True`` (with ``extrapolate``): the estimate also covers the change against a
    non-nested extrapolated solve with ``9 N / 8`` steps (:func:`_checked`; about 1.1 times the
    work again), which sees errors that every nested coarser level shares.
    Without a modal basis (the fallback) no extrapolation is done: in the
    model's coordinates the midpoint error is not in its asymptotic range.
    ``collapse=True`` (default): nested frames are propagated in their composite basis
    (:class:`CollapsedModalSystem`: the same ``P_hat`` up to rounding, one product and one LU
    solve per time instead of one per frame); ``False`` evaluates frame by frame.
    """
    from stability.floquet import floquet

    if basis is not None:
        if collapse:
            basis._collapsed_table()  # formed once on the given basis: its with_system copies share it
        system = _rebase(basis, P)
    else:
        try:
            system = modal_system(P, levels, samples, options.get("period"))
        except ModalBasisError as exc:
            warnings.warn(f"no frozen-modal basis ({exc}): Floquet falls back to adaptive {FALLBACK_METHOD} "
                          f"(n_steps=None) in the model's own coordinates", RuntimeWarning, stacklevel=2)
            fallback = {k: v for k, v in options.items() if k not in ("method", "n_steps", "error_estimate")}
            res = floquet(P, method=FALLBACK_METHOD, n_steps=None, **fallback)
            return _with_frame(res, "model", 0, str(exc))
    # its exponents are nearly block diagonal over the frame's clusters: cheaper exact expm
    options.setdefault("expm_blocks", tuple(system.clusters))
    frame, system = system, (system.collapsed() if collapse else system)  # propagate in one basis
    steps = options.get("n_steps")
    if (extrapolate and steps is None and options.get("method", "magnus6") == "magnus2"
            and options.get("small_multipliers", "flag") != "qr"):
        res = _adaptive_extrapolated(system, options, check)
        return _with_frame(replace(res, monodromy=_to_base(frame, res.monodromy)), "modal", _levels(frame))
    can_extrapolate = (extrapolate and steps is not None and int(steps) >= 8
                       and options.get("method", "magnus6") == "magnus2"
                       and options.get("small_multipliers", "flag") != "qr")
    # ratio 3 (N divisible by 9: N / 3 and N / 9 come with the N-step solve of a large system) or 2
    by_nine = can_extrapolate and int(steps) % 9 == 0
    fine = floquet(system, **dict(options, error_estimate=True)) if by_nine else None
    if by_nine and len(fine.companion_monodromies) == 2:
        res = _extrapolated(system, fine, options)
    elif can_extrapolate and int(steps) % 4 == 0:
        res = _extrapolated(system, floquet(system, **dict(options, error_estimate=False)), options)
    elif fine is not None:
        res = fine
    else:
        res = floquet(system, **options)
    if check and can_extrapolate and res is not fine:
        res = _checked(system, res, options)
    return _with_frame(replace(res, monodromy=_to_base(frame, res.monodromy)), "modal", _levels(frame))
