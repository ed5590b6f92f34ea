"""Floquet multipliers of a second-order periodic system by Hill's method (harmonic balance).

An independent check of the time-stepping Floquet methods: no propagator, no
step count, so the stiff high-frequency modes of a finite-element model (the
axial modes of ANCF beams, kHz against an excitation of 1-2 Hz) cost nothing
here, while they make an exponential-midpoint product converge erratically in
its step count (step-size resonances ``h omega ~ 2 pi m``).

Maths
-----
The system ``M(t) y'' + C(t) y' + K(t) y = 0`` has T-periodic trigonometric
polynomials ``M, C, K = sum_{|m| <= N/2} X_m e^{i m W t}`` (``W = 2 pi / T``)
given by their samples at ``t_k = k T / N`` (``N`` even; the Nyquist term is
the cosine, as in :mod:`linearize.fourier`: ``X_{+-N/2} = c_{N/2} / 2``).
A Floquet solution ``y = e^{lambda t} sum_{|k| <= H} p_k e^{i k W t}``
satisfies, harmonic by harmonic (``s_k = lambda + i k W``),

    sum_k [ M_{j-k} s_k^2 + C_{j-k} s_k + K_{j-k} ] p_k = 0,    |j| <= H,

a quadratic eigenvalue problem ``(lambda^2 A2 + lambda A1 + A0) p = 0`` with
``A2 = [M_{j-k}]``, ``A1 = [2 i k W M_{j-k} + C_{j-k}]``,
``A0 = [(i k W)^2 M_{j-k} + i k W C_{j-k} + K_{j-k}]`` (Hill's infinite
determinant, truncated).  Its companion pencil ``A - lambda B``,
``A = [[0, I], [-A0, -A1]]``, ``B = diag(I, A2)``, is solved near a shift
``sigma`` by shift-invert (inverse / Rayleigh-quotient) iteration; ``(A - sigma B)^-1`` needs only the sparse
LU of ``Q(sigma) = A0 + sigma A1 + sigma^2 A2`` (block band of width ``N/2``).
The multiplier is ``rho = exp(lambda T)``.

Every exponent appears with its copies ``lambda + i k W``; the copy whose
coefficients ``p_k`` are centred on ``k = 0`` is the accurate one under
truncation.  Each target is refined to that copy (shift to the harmonic
centroid of the eigenvector, solve again).  The truncation error is estimated
by repeating with ``H/2`` harmonics (spectral convergence: the difference
bounds the error of the coarser, so over-estimates that of ``H``).

References
----------
.. [1] Hill, G. W., "On the part of the motion of the lunar perigee which is a
       function of the mean motions of the sun and moon", Acta Math. 8 (1886) 1-36.
.. [2] Lazarus, A., Thomas, O., "A harmonic-based method for computing the
       stability of periodic solutions of dynamical systems", C. R. Mecanique
       338 (2010) 510-517.
.. [3] Deconinck, B., Kutz, J. N., "Computing spectra of linear operators
       using the Floquet-Fourier-Hill method", J. Comput. Phys. 219 (2006) 296-321.
"""
from __future__ import annotations

import cmath
import math
import time
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from stability.frozen import frozen_result

__all__ = ["HillResult", "HillError", "hill_multipliers", "fourier_coefficients", "DEFAULT_HARMONICS",
           "RESIDUAL_LIMIT", "TAIL_LIMIT", "pair_error_estimate"]

#: Harmonics ``H`` of the Floquet vector (``2 H + 1`` blocks).
DEFAULT_HARMONICS = 48
#: Inverse iteration stops when the exponent changes by less than this (relative to max(|lambda|, 1)).
EIG_RTOL = 1e-14
#: Cap on inverse-iteration steps per shift.
MAX_ITERATIONS = 60
#: Extra inverse-iteration steps on the vector (``lambda`` kept) after ``lambda`` has converged ...
POLISH_STEPS = 3
#: ... until the residual reaches this (~10 eps, the rounding of forming ``Q(lambda) p`` in its scaling).
POLISH_TARGET = 10 * np.finfo(float).eps
#: Up to this many unknowns ``n (2 H + 1)`` the Hill matrices are dense (LAPACK LU), sparse beyond.
DENSE_LIMIT = 3000
#: A pair whose backward error :attr:`HillResult.residual` exceeds this is not an eigenpair of the truncated
#: problem (:attr:`HillResult.unconverged`).  The residual is scaled by ``(|A0| + |lambda| |A1| +
#: |lambda|^2 |A2|) |p|`` (see ``_HillOperator.residual``), so forming ``Q(lambda) p`` in floating point reads
#: ~eps for an exact pair once the vector is polished (``POLISH_STEPS``; measured: two-link arm, 1 element,
#: H = 16: 1.1e-16 .. 1.7e-16; rotating frame, H = 6: 6.5e-17 .. 2.1e-15).  Derivation:
#: the iteration stops when ``lambda`` changes by less than ``EIG_RTOL = 1e-14`` (~45 eps) relative, which
#: leaves a backward error of about that change (``|Q'(lambda)| |lambda| / |Q|`` is O(1) in this scaling),
#: ~1e2 eps; the LU solves add ~sqrt(N) eps (partial pivoting, N <= 1e5 unknowns: <= 316 eps).  ``1e3 eps``
#: (2.2e-13) is above both.  (The former scaling, by the largest block entry, read 1e-21 .. 1e-18 on converged
#: two-link pairs, so this limit passed pairs stopped early with errors up to 7.7e-5.)
RESIDUAL_LIMIT = 1e3 * np.finfo(float).eps
#: A pair whose Floquet vector keeps more than this fraction of its energy in the outer quarter of the
#: harmonics (:attr:`HillResult.tail`) is flagged as truncated (:attr:`HillResult.truncated`).  Heuristic:
#: to first order the relative change of the eigenvalue is of the relative amplitude of the outermost retained
#: coefficients, ``sqrt(tail)``, and a tuning tolerance of ``1e-3 rho_d`` asks ``sqrt(tail) <= 1e-3``.  This is
#: an indicator, NOT a bound: on damped Mathieu (q = 40, H = 10) the tail is 8.7e-7 while the multiplier is
#: 9.4e-3 off (the coefficients decay slowly over the outer 2-3 harmonics).  The bound is the
#: H vs H/2 change (:func:`pair_error_estimate`, or ``error_estimate=True``): spectral convergence makes it
#: bound the error of ``H/2``, so over-state that of ``H``.
TAIL_LIMIT = 1e-6


class HillError(ArithmeticError):
    """No eigenvalue found near a target (or the shifted matrix is singular)."""


@frozen_result
@dataclass(frozen=True)
class HillResult:
    """Multipliers near the targets by Hill's method.

    Attributes
    ----------
    multipliers : ndarray of complex, shape (m,)
        ``exp(lambda T)`` of the exponent found nearest each target (centred copy).
    exponents : ndarray of complex, shape (m,)
        The centred exponents ``lambda``.
    targets : ndarray of complex, shape (m,)
        The target multipliers (from another method, or a guess).
    harmonics : int
        ``H``.
    error_estimate : ndarray, shape (m,)
        ``|rho_H - rho_{H/2}| / max(|rho_H|, 1e-300)`` (relative); NaN if not computed.
    tail : ndarray, shape (m,)
        Fraction of the eigenvector's energy (``sum |p_k|^2``) in the outer quarter
        ``|k| > 3 H / 4`` of the harmonics (a truncation indicator).
    residual : ndarray, shape (m,)
        ``||Q(lambda) p|| / ||(|A0| + |lambda| |A1| + |lambda|^2 |A2|) |p| ||``: backward error of the pair
        (~eps when converged).
    period : float
    size : int
        ``n`` (second-order coordinates).
    elapsed : float
        Seconds.
    states : ndarray of complex, shape (m, 2 n)
        The Floquet solution's state ``[y(0); y'(0)]`` per multiplier
        (``y(0) = sum_k p_k``, ``y'(0) = sum_k (lambda + i k W) p_k``): the
        monodromy's eigenvector, for mode labels.
    """

    multipliers: np.ndarray
    exponents: np.ndarray
    targets: np.ndarray
    harmonics: int
    error_estimate: np.ndarray
    tail: np.ndarray
    residual: np.ndarray
    period: float
    size: int
    elapsed: float = field(default=0.0, compare=False)
    states: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    @property
    def truncated(self) -> np.ndarray:
        """Per multiplier: ``tail > TAIL_LIMIT`` (too few harmonics for this Floquet vector)."""
        return np.asarray(self.tail) > TAIL_LIMIT

    @property
    def unconverged(self) -> np.ndarray:
        """Per multiplier: ``residual > RESIDUAL_LIMIT`` (not an eigenpair of the truncated problem)."""
        return np.asarray(self.residual) > RESIDUAL_LIMIT

    def to_dict(self) -> dict:
        c = lambda z: [float(np.real(z)), float(np.imag(z))]  # noqa: E731
        return {
            "method": "hill",
            "harmonics": self.harmonics,
            "multipliers": [c(z) for z in self.multipliers],
            "moduli": [float(abs(z)) for z in self.multipliers],
            "targets": [c(z) for z in self.targets],
            "error_estimate": [float(v) for v in self.error_estimate],
            "tail": [float(v) for v in self.tail],
            "residual": [float(v) for v in self.residual],
            "truncated": [bool(v) for v in self.truncated],
            "unconverged": [bool(v) for v in self.unconverged],
            "period": self.period,
            "size": self.size,
            "elapsed": self.elapsed,
        }


def fourier_coefficients(samples: np.ndarray) -> np.ndarray:
    """Complex coefficients ``X_m``, ``m = -N/2..N/2`` (axis 0, index ``m + N/2``) of the samples' interpolant.

    The trigonometric interpolant of ``N`` equispaced samples with the Nyquist
    term as a cosine (``X_{+-N/2} = c_{N/2} / 2``), the convention of
    :func:`linearize.fourier.trig_interpolate`.
    """
    y = np.asarray(samples, dtype=float)
    N = y.shape[0]
    if N < 2 or N % 2:
        raise ValueError(f"need an even number of samples >= 2, got {N}")
    c = np.fft.fft(y, axis=0) / N  # c[m] for m = 0..N-1 (m > N/2 are negative harmonics)
    h = N // 2
    out = np.empty((N + 1,) + y.shape[1:], dtype=complex)
    for m in range(-h, h + 1):
        out[m + h] = c[m % N]
    out[0] *= 0.5  # -N/2 and +N/2 share c_{N/2}: half each
    out[-1] = out[0]
    return out


class _HillOperator:
    """The truncated Hill matrices ``A0, A1, A2`` for one harmonic count (dense up to
    :data:`DENSE_LIMIT` unknowns, sparse beyond), and eigenpairs of their pencil near a shift."""

    def __init__(self, Mc: np.ndarray, Cc: np.ndarray, Kc: np.ndarray, period: float, H: int) -> None:
        n = Mc.shape[1]
        h = (Mc.shape[0] - 1) // 2
        W = 2.0 * math.pi / period
        size = n * (2 * H + 1)
        ks = np.arange(-H, H + 1)
        diff = ks[:, None] - ks[None, :]  # j - k
        inside = np.abs(diff) <= h
        idx = np.clip(diff + h, 0, 2 * h)
        ikw = (1j * W * ks)[None, :, None, None]  # i k W of the column block
        Mb = Mc[idx] * inside[..., None, None]
        Cb = Cc[idx] * inside[..., None, None]
        Kb = Kc[idx] * inside[..., None, None]
        blocks = {
            "A2": Mb,
            "A1": 2.0 * ikw * Mb + Cb,
            "A0": ikw * ikw * Mb + ikw * Cb + Kb,
        }
        self.dense = size <= DENSE_LIMIT
        for name, b in blocks.items():
            a = b.transpose(0, 2, 1, 3).reshape(size, size)
            setattr(self, name, a if self.dense else scipy.sparse.csc_matrix(a))
        self.n, self.H, self.W, self.size = n, H, W, size
        self._abs = None
        self.scale = float(max(np.abs(blocks[k]).max() for k in blocks)) or 1e-300

    def _factor(self, s: complex):
        Q = self.A0 + s * self.A1 + (s * s) * self.A2
        if self.dense:
            lu = scipy.linalg.lu_factor(Q, check_finite=False)
            if np.any(np.diag(lu[0]) == 0):
                raise HillError(f"Hill matrix singular at the shift {s}")
            return lambda b: scipy.linalg.lu_solve(lu, b, check_finite=False)
        try:
            f = scipy.sparse.linalg.splu(Q.tocsc())
        except RuntimeError as exc:
            raise HillError(f"Hill matrix singular at the shift {s}: {exc}") from None
        return f.solve

    def nearest(self, sigma: complex) -> tuple[complex, np.ndarray]:
        """Eigenpair ``(lambda, p)`` of the pencil nearest ``sigma`` (shift-invert iteration).

        Inverse iteration on ``(A - sigma B)^-1 B`` (companion form, solved through
        ``Q(sigma)``), the shift moved to the current estimate when the iteration is slow
        (Rayleigh-quotient iteration); stops when the eigenvalue changes by less than
        :data:`EIG_RTOL` relative.
        """
        N = self.size
        rng = np.random.default_rng(0)
        x = rng.standard_normal(2 * N) + 1j * rng.standard_normal(2 * N)
        lam = complex(sigma)
        shift = complex(sigma)
        solve = self._factor(shift)
        last = None
        for it in range(MAX_ITERATIONS):
            u, v = x[:N], x[N:]
            uu = -solve(self.A2 @ v + (self.A1 + shift * self.A2) @ u)
            y = np.concatenate([uu, u + shift * uu])
            theta = complex(np.vdot(x, y) / np.vdot(x, x))
            if theta == 0 or not np.isfinite(theta):
                raise HillError(f"no eigenvalue found near {sigma}")
            lam_new = shift + 1.0 / theta
            x = y / np.linalg.norm(y)
            if last is not None and abs(lam_new - lam) <= EIG_RTOL * max(abs(lam_new), 1.0):
                lam = lam_new
                break
            if last is not None and abs(lam_new - lam) > 0.1 * abs(lam - last) and it % 4 == 3:
                shift = lam_new  # slow: Rayleigh-quotient shift
                solve = self._factor(shift)
            last, lam = lam, lam_new
        else:
            raise HillError(f"inverse iteration near {sigma} did not converge in {MAX_ITERATIONS} steps "
                            f"(last change {abs(lam_new - last):.2e})")
        # the Rayleigh quotient converges about twice as fast as the vector: polish the vector (lambda kept) so
        # that the residual measures lambda's backward error, not the vector's lag (rotating frame: 5.6e-13 -> ~eps)
        for _ in range(POLISH_STEPS):
            if self.residual(lam, x[:N]) <= POLISH_TARGET:
                break
            u, v = x[:N], x[N:]
            uu = -solve(self.A2 @ v + (self.A1 + shift * self.A2) @ u)
            y = np.concatenate([uu, u + shift * uu])
            x = y / np.linalg.norm(y)
        return lam, x[:N]

    def harmonic_energy(self, p: np.ndarray) -> np.ndarray:
        return np.sum(np.abs(p.reshape(2 * self.H + 1, self.n)) ** 2, axis=1)

    def residual(self, lam: complex, p: np.ndarray) -> float:
        """Backward error ``||Q(lambda) p|| / ||(|A0| + |lambda| |A1| + |lambda|^2 |A2|) |p|| ||``: the
        rounding of forming ``Q(lambda) p`` alone is ~``n_nz eps`` of the denominator, whatever the scales of
        the rows (stiff axial vs soft drive rows) and of ``lambda``."""
        r = (self.A0 + lam * self.A1 + lam * lam * self.A2) @ p
        a = abs(lam)
        ap = np.abs(p)
        if self._abs is None:  # |A0|, |A1|, |A2|, formed once
            self._abs = tuple(np.abs(m) if self.dense else abs(m) for m in (self.A0, self.A1, self.A2))
        a0, a1, a2 = self._abs
        s = np.asarray(a0 @ ap + a * (a1 @ ap) + a * a * (a2 @ ap)).ravel()
        den = float(np.linalg.norm(s))
        return float(np.linalg.norm(r) / den) if den > 0 else math.inf


def _centred(op: _HillOperator, sigma: complex) -> tuple[complex, np.ndarray]:
    lam, p = op.nearest(sigma)
    for _ in range(3):
        e = op.harmonic_energy(p)
        ks = np.arange(-op.H, op.H + 1)
        k0 = int(round(float(np.sum(ks * e) / max(float(np.sum(e)), 1e-300))))
        if k0 == 0:
            break
        # p concentrated at harmonic k0: the copy lambda + i k0 W has it at 0
        lam, p = op.nearest(lam + 1j * k0 * op.W)
    return lam, p


def hill_multipliers(
    M: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    period: float,
    targets: Sequence[complex],
    *,
    harmonics: int = DEFAULT_HARMONICS,
    error_estimate: bool = True,
) -> HillResult:
    """Floquet multipliers near ``targets`` of ``M y'' + C y' + K y = 0`` by Hill's method.

    Parameters
    ----------
    M, C, K : ndarray, shape (N, n, n)
        Samples at ``k T / N`` (``N`` even) of T-periodic matrices; the system solved
        is their trigonometric interpolant (Nyquist term a cosine), which is exact for
        trigonometric polynomials of degree ``< N/2``.
    period : float
        ``T``.
    targets : sequence of complex
        Approximate multipliers (e.g. from a time-stepping method); for each, the
        exponent nearest ``log(target) / T`` is found and centred.
    harmonics : int
        ``H`` (``2 H + 1`` harmonics of the Floquet vector), ``>= 2``.
    error_estimate : bool
        Repeat with ``H // 2`` harmonics and report the relative change.

    Returns
    -------
    HillResult

    Raises
    ------
    ValueError
        Bad shapes, non-finite entries, zero target.
    HillError
        No eigenvalue found near a target.
    """
    t0 = time.perf_counter()
    mats = [np.asarray(a, dtype=float) for a in (M, C, K)]
    if any(a.ndim != 3 or a.shape != mats[0].shape or a.shape[1] != a.shape[2] for a in mats):
        raise ValueError(f"M, C, K must be (N, n, n) samples of equal shape, got {[a.shape for a in mats]}")
    if not all(np.all(np.isfinite(a)) for a in mats):
        raise ValueError("M, C, K contain NaN or inf")
    if not (math.isfinite(period) and period > 0):
        raise ValueError(f"period must be finite and > 0, got {period!r}")
    if isinstance(harmonics, bool) or int(harmonics) != harmonics or harmonics < 2:
        raise ValueError(f"harmonics must be an integer >= 2, got {harmonics!r}")
    tg = np.atleast_1d(np.asarray(targets, dtype=complex))
    if tg.size == 0 or not np.all(np.isfinite(tg)) or np.any(tg == 0):
        raise ValueError(f"targets must be finite non-zero multipliers, got {targets!r}")
    Mc, Cc, Kc = (fourier_coefficients(a) for a in mats)
    H = int(harmonics)
    op = _HillOperator(Mc, Cc, Kc, float(period), H)
    coarse = _HillOperator(Mc, Cc, Kc, float(period), max(2, H // 2)) if error_estimate else None
    mus, lams, est, tails, res, states = [], [], [], [], [], []
    for target in tg:
        sigma = cmath.log(complex(target)) / period
        lam, p = _centred(op, sigma)
        mu = cmath.exp(lam * period)
        e = op.harmonic_energy(p)
        outer = np.abs(np.arange(-H, H + 1)) > 0.75 * H
        tails.append(float(np.sum(e[outer]) / max(float(np.sum(e)), 1e-300)))
        res.append(op.residual(lam, p))
        P = p.reshape(2 * H + 1, op.n)
        s_k = lam + 1j * op.W * np.arange(-H, H + 1)
        states.append(np.concatenate([P.sum(axis=0), (s_k[:, None] * P).sum(axis=0)]))
        if coarse is not None:
            lam_c, _ = _centred(coarse, lam)
            est.append(abs(cmath.exp(lam_c * period) - mu) / max(abs(mu), 1e-300))
        else:
            est.append(math.nan)
        mus.append(mu)
        lams.append(lam)
    return HillResult(
        multipliers=np.array(mus), exponents=np.array(lams), targets=tg, harmonics=H,
        error_estimate=np.array(est), tail=np.array(tails), residual=np.array(res), period=float(period),
        size=int(mats[0].shape[1]), elapsed=time.perf_counter() - t0, states=np.array(states),
    )


def pair_error_estimate(M: np.ndarray, C: np.ndarray, K: np.ndarray, period: float,
                        multipliers: Sequence[complex], harmonics: int) -> np.ndarray:
    """Relative H vs H/2 change ``|rho_{H/2} - rho| / |rho|`` of multipliers already refined with ``harmonics``.

    One solve of the ``H // 2`` problem per multiplier, shifted at the value itself (the
    ``error_estimate=True`` estimate of :func:`hill_multipliers`, for chosen pairs only).  Spectral
    convergence: the change bounds the error of ``H/2``, so over-states that of ``H``.  ``inf`` where the
    coarse problem has no eigenvalue near the value (:class:`HillError`): no estimate, not a pass.
    """
    rho = np.atleast_1d(np.asarray(multipliers, dtype=complex))
    out = np.full(rho.shape, math.inf)
    for i, z in enumerate(rho):
        try:
            c = hill_multipliers(M, C, K, period, [z], harmonics=max(2, int(harmonics) // 2), error_estimate=False)
        except HillError:
            continue
        out[i] = abs(complex(c.multipliers[0]) - z) / max(abs(z), 1e-300)
    return out
