"""Floquet multipliers of a T-periodic linear system ``x' = P(t) x``.

Public entry point: :func:`floquet`.  Methods live in the registry
:data:`METHODS`:

``"magnus6"`` (default)
    6th-order Magnus exponential propagator on ``N`` equal sub-intervals (equal
    on each smooth piece between declared breakpoints), vectorised.  Adaptive: the
    first ``N`` from the size of the commutator terms, a pilot ``N/2, N, 2N``, then
    refinement passes sized by the error model ``err ~ C N^-q`` (``q`` the observed
    order, at most 6) until the estimate of the moduli (or, with
    ``accuracy="multipliers"``, of the complex multipliers) is below ``rtol``
    (:func:`_level_estimates`: pairing by assignment, the observed order, a safety
    factor, Henrici bounds for defective groups).  Exact for constant ``P`` and
    unconditionally stable for stiff, strongly damped systems (each
    sub-interval propagator is a matrix exponential).
``"magnus4"``
    The same with the 4th-order, two-point scheme.
``"magnus2"``
    The exponential midpoint rule ``prod exp(h P(t_k + h/2))`` (2nd order).
    The robust choice when ``h ||P||`` is large and ``P`` varies (the Exudyn
    linearisation, ``||P|| ~ 4e5 1/s``): it has no commutator terms, which
    in the higher-order schemes grow like ``(h ||P||)^2`` and more.
``"paper"``
    The paper's procedure (Eqs. 7-8): ``n`` integrations from the unit
    vectors with ``scipy.integrate.solve_ivp`` (Radau with the exact
    Jacobian).  Slow; kept as the independent reference.

Small multipliers: the multipliers are the eigenvalues of the formed
monodromy matrix, so their absolute accuracy is about
``eps * prod ||E_k||`` (:attr:`FloquetResult.noise_floor`).  In strongly
damped systems the true small multipliers (``1e-1400`` is typical for the
controlled manipulator) lie far below that floor; the result flags them in
:attr:`FloquetResult.reliable` instead of presenting noise as digits.
Liouville's formula is checked on ``log det Phi`` accumulated from the
factors (exact in log form even when ``det Phi`` underflows) and, when every
multiplier is above the noise floor, on the multipliers themselves.
"""
from __future__ import annotations

import cmath
import functools
import itertools
import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np
from scipy.linalg.lapack import dgebal, dgeev, dgesdd

from stability.expm import expm_near_block_diagonal, expm_soa, expm_stack
from stability.magnus import (
    MAGNUS2,
    MAGNUS4,
    MAGNUS6,
    MagnusScheme,
    magnus_exponents,
    magnus_exponents_soa,
    ordered_product,
    ordered_product_interleaved,
    ordered_product_soa,
)
from stability.frozen import frozen_result
from stability.periodic import PeriodicMatrixFunction
from stability.reference import ReferenceOptions, paper_monodromy
from stability.serialization import json_ready

__all__ = [
    "FloquetResult",
    "FloquetError",
    "floquet",
    "METHODS",
    "DEFAULT_METHOD",
    "VERDICT_STABLE",
    "VERDICT_UNSTABLE",
    "VERDICT_CRITICAL",
    "ACCURACIES",
    "DOMINANT_BAND",
    "DOMINANT_SAFETY",
    "dominant_mask",
    "CONTRACT_RTOL",
    "DEFAULT_RTOL",
    "recertify",
]

logger = logging.getLogger(__name__)

# the verdict rule lives in stability.verdict (one rule for every route; re-exported here)
from stability.verdict import VERDICT_CRITICAL, VERDICT_STABLE, VERDICT_UNSTABLE, verdict_band  # noqa: E402

DEFAULT_METHOD = "magnus6"
#: Upper limit on sub-intervals before the adaptive methods give up refining.
MAX_STEPS = 2**15
#: The accuracy contract (``docs/accuracy.md``): by default every multiplier with modulus
#: ``>= ESTIMATE_FLOOR`` of the largest is certified to this relative error (moduli; phases too
#: with ``accuracy="multipliers"``) or reported uncertified with the reason
#: (:attr:`FloquetResult.certified`, :attr:`FloquetResult.uncertified_reasons`).
CONTRACT_RTOL = 1e-6
#: Default ``rtol`` of :func:`floquet`.  The estimate it is met by carries the safety factor
#: :data:`ESTIMATE_SAFETY` = 2, so 2e-9 asks for the work that the former unguarded estimate
#: spent on 1e-9 (whose true error it equalled only to within its own accuracy).
DEFAULT_RTOL = 2e-9
#: Moduli below this fraction of the spectral radius are not used for the
#: error estimate (their absolute error is what matters for stability).
ESTIMATE_FLOOR = 1e-6
#: What an error estimate can certify (``floquet(accuracy=...)``): every modulus >= ESTIMATE_FLOOR
#: of the largest, every multiplier (moduli and phases) there, or the spectral radius and the
#: multipliers that could be it (:func:`dominant_mask`).
ACCURACIES = ("moduli", "multipliers", "dominant")
#: ``accuracy="dominant"`` (:func:`dominant_mask`): the estimate covers every multiplier whose
#: modulus is within this relative band of the spectral radius, ...
DOMINANT_BAND = 1e-6
#: ... and every multiplier whose error interval widened by this factor reaches the spectral
#: radius' (the largest measured miss of the extrapolated estimate on one multiplier: 8x, the
#: 8-element single link at 144 steps, ``stability.modal._extrapolated``).
DOMINANT_SAFETY = 10.0
#: Largest number of points of the periodic trapezoidal rule for the Liouville
#: trace integral (spectrally accurate for smooth periodic integrands; independent
#: of the Gauss points the Magnus methods use).  The rule is nested: it starts
#: with ``TRACE_MIN_POINTS // 2`` points and doubles until two successive sums
#: agree to :data:`TRACE_RTOL` (at least ``TRACE_MIN_POINTS`` points), so a
#: large system whose ``P`` costs milliseconds per evaluation (a 516-state
#: linearisation: 40 ms) is not evaluated 512 times for one scalar.
TRACE_POINTS = 512
#: Fewest points of the trace rule (two nested sums of 32 and 64 points must agree).
TRACE_MIN_POINTS = 64
#: Agreement of two nested trace sums, relative to ``int |tr P| dt``: the
#: trapezoidal error of a smooth periodic integrand falls exponentially with the
#: points, so the change from ``K`` to ``2 K`` bounds the error of the ``K`` sum;
#: 1e-13 is above the rounding of a 512-term sum (~ 9 eps).
TRACE_RTOL = 1e-13
#: Unit roundoff times 2 (``np.finfo(float).eps``), as a plain float.
_EPS = float(np.finfo(float).eps)


@frozen_result
@dataclass(frozen=True)
class FloquetResult:
    """Floquet analysis of ``x' = P(t) x`` over one period.

    The accuracy contract (``docs/accuracy.md``): every multiplier with modulus ``>=
    ESTIMATE_FLOOR`` (1e-6) of the largest is within ``rtol`` relative of the exact multiplier of
    ``P`` -- in modulus, and in phase too with ``accuracy="multipliers"`` -- when
    :attr:`certified` says so; the adaptive engine refines until it does, or stops at the step
    limit / the rounding level and says for each multiplier that missed it why
    (:attr:`uncertified_reasons`, a ``RuntimeWarning``).  ``rtol`` is the call's (default
    :data:`DEFAULT_RTOL`; the CLI certifies :data:`CONTRACT_RTOL`, 1e-6, unless ``--rtol``).  The
    estimates behind it are bounds by rule, not Richardson values alone: the spectra of the
    refinement levels are paired by assignment; the order of convergence is observed over three
    levels and the extrapolation uses it when it is lower than the scheme's (a non-smooth ``P``
    without declared :attr:`breakpoints` shows as a low :attr:`observed_order`); a safety factor
    :data:`ESTIMATE_SAFETY`; defective or clustered multipliers get Henrici's (square-root) bound
    with a warning naming them; nothing is claimed below the rounding level of the product.  A
    multiplier below the rounding floor has its modulus (``log_moduli``, exact with
    ``small_multipliers="qr"``) but no phase or sign (:attr:`phase_known` False; ``to_dict`` prints
    ``null`` for it and :attr:`exponents` a NaN imaginary part).

    Attributes
    ----------
    multipliers : ndarray, complex, shape (n,)
        Floquet multipliers (eigenvalues of the monodromy matrix), sorted by
        modulus, descending.  Moduli below ~1e-308 underflow to 0 here; see
        ``log_moduli``.
    log_moduli : ndarray, shape (n,)
        ``ln |rho_i|`` in the same order (``-inf`` for an exactly zero one).
    monodromy : ndarray, shape (n, n)
        ``Phi(T)``, the formed product.
    spectral_radius : float
        ``max |rho_i|``.
    verdict : str
        ``"asymptotically stable"``, ``"unstable"`` or ``"critical"``: the rule of
        :mod:`stability.verdict` on the spectral radius and its band (stable only if
        ``rho + tol <= exp(-1/1000)``, unstable only if ``rho - tol > 1``); with mode labels,
        :func:`stability.verdict.judge_floquet`.
    stability_tolerance : float
        The absolute error band of the spectral radius (the requested
        tolerance, widened to the estimated error when that is larger).
    liouville_residual : float
        ``|det Phi(T) / exp(int_0^T tr P dt) - 1|`` in log form,
        ``|expm1(ln|det Phi| - int tr P)|``, so that it stays meaningful when
        ``det Phi`` underflows (1e-1400 in the controlled manipulator).
        ``ln|det Phi|`` is ``sum ln|rho_i|`` of the returned multipliers when
        all of them are above the noise floor (``liouville_source =
        "multipliers"``); otherwise the multipliers cannot carry it, and it is
        accumulated from the propagators (``"propagators"``: ``sum tr
        Omega_k`` for Magnus, which checks the quadrature of ``tr P`` only).
    liouville_source : str
        ``"multipliers"`` or ``"propagators"`` (see above), or
        ``"unavailable"`` (NaN residual) for the ``"paper"`` method when
        some multiplier is below the noise floor: it keeps no propagators,
        and ``det`` of the formed matrix is then rounding noise.
    multiplier_liouville_residual : float
        The same identity checked on the returned multipliers,
        ``|expm1(sum ln|rho_i| - int tr P)|``; NaN when some multiplier is
        below the noise floor (then it cannot be checked from them).
    trace_integral : float
        ``int_0^T tr P dt`` (closed form when the model supplies it,
        otherwise the periodic trapezoidal rule on ``TRACE_POINTS`` points).
    error_estimate : float
        Estimate (by the rules above) of the largest relative error, over the
        multipliers with moduli ``>= ESTIMATE_FLOOR * spectral_radius``, of
        what ``accuracy`` names: the moduli (default) or the multipliers
        (moduli and phases); with ``"dominant"`` the moduli of
        :func:`dominant_mask`'s multipliers only; NaN when not computed.
    noise_floor : float
        ``n eps ||Phi||``: absolute level below which moduli read from the
        formed monodromy matrix are rounding noise (a lower bound: non-normal
        monodromy matrices amplify it by the eigenvalue condition number).
    reliable_digits : ndarray, shape (n,)
        Per multiplier, ``-log10`` of its own error estimate (by the rules above, capped at 16),
        further capped by the noise floor; 0 means the value is noise.
    method : str
    n_steps : int
        Sub-intervals of the final propagation (factor methods) or accepted
        steps of ``solve_ivp`` summed over the columns (``"paper"``).
    n_evaluations : int
        Evaluations of ``P(t)`` (all refinements included).
    period : float
    elapsed : float
        Wall time in seconds.
    accuracy : str
        What ``error_estimate`` certifies: ``"moduli"`` (every modulus
        ``>= ESTIMATE_FLOOR`` of the largest), ``"multipliers"`` (moduli and
        phases there) or ``"dominant"`` (the spectral radius and the moduli of
        the multipliers that could be it, :func:`dominant_mask`; the verdict
        needs only these).  ``reliable_digits`` is per multiplier whatever it is.
    phase_error_estimate : float
        Richardson estimate of the largest phase error (radians, = relative
        error of the multiplier's direction) from the same refinement; it is
        reported whatever ``accuracy`` is, but the refinement drives it below
        ``rtol`` only with ``accuracy="multipliers"``.  NaN when not computed.
    rtol : float
        The relative accuracy :attr:`certified` is judged against.
    certified : ndarray of bool, shape (n,)
        Per multiplier: modulus ``>= ESTIMATE_FLOOR`` of the largest, above the rounding floor,
        covered by ``accuracy``, and estimated error (``10^-reliable_digits``) ``<= rtol``.
    uncertified_reasons : tuple of str
        Per multiplier, ``""`` when certified, otherwise why not (outside the contract's range,
        phase unknown below the rounding floor, estimate above ``rtol`` with its cause: a
        defective group, a low observed order, the step limit, the rounding level).
    phase_known : ndarray of bool, shape (n,)
        ``False`` where the multiplier is below ``100 * noise_floor``: its phase (a real
        multiplier's sign) is rounding noise.
    observed_order : float
        Smallest order of convergence observed over the last three refinement levels among the
        covered multipliers (NaN when the changes were at the rounding level or fewer than
        three levels ran).  Well below the method's order: ``P`` is non-smooth inside the period.
    breakpoints : tuple of float
        The times in ``(0, T)`` the sub-intervals landed on (``floquet(breakpoints=...)`` or
        ``P.breakpoints``).
    companion_steps, companion_monodromies : tuple
        ``magnus2`` with a fixed ``n_steps = N`` (a multiple of 3) on a system
        larger than ``SMALL_N`` with ``error_estimate``: the step counts
        ``N / 3`` (and ``N / 9`` when 9 divides ``N``) and the monodromy matrices
        of the exponential midpoint rule with them, formed from the factors of
        the ``N``-step solve (``expm(3 h P) = expm(h P)^3``, no new exponentials);
        the ``N / 3`` one gives ``error_estimate``.  Empty otherwise.  For
        Richardson extrapolation with ratio 3 (e.g. :mod:`stability.modal`).
    """

    multipliers: np.ndarray
    log_moduli: np.ndarray
    monodromy: np.ndarray
    spectral_radius: float
    verdict: str
    stability_tolerance: float
    liouville_residual: float
    liouville_source: str
    multiplier_liouville_residual: float
    trace_integral: float
    error_estimate: float
    noise_floor: float
    reliable_digits: np.ndarray
    method: str
    n_steps: int
    n_evaluations: int
    period: float
    elapsed: float = 0.0
    accuracy: str = "moduli"
    phase_error_estimate: float = math.nan
    companion_steps: tuple = ()
    companion_monodromies: tuple = ()
    rtol: float = math.nan
    certified: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    uncertified_reasons: tuple = ()
    phase_known: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    observed_order: float = math.nan
    breakpoints: tuple = ()

    def _known(self) -> np.ndarray:
        if self.phase_known.size == self.multipliers.size:
            return self.phase_known
        return np.ones(self.multipliers.size, bool)

    @property
    def all_certified(self) -> bool:
        """Every multiplier the contract covers (modulus >= ``ESTIMATE_FLOOR`` of the largest) is certified."""
        if self.certified.size == 0:
            return False
        covered = self.log_moduli >= self.log_moduli[0] + math.log(ESTIMATE_FLOOR)
        return bool(np.all(self.certified[covered]))

    @property
    def moduli(self) -> np.ndarray:
        """``|rho_i|``, descending."""
        with np.errstate(under="ignore"):
            return np.exp(self.log_moduli)

    @property
    def exponents(self) -> np.ndarray:
        """Characteristic (Floquet) exponents ``ln(rho_i) / T`` (principal branch); the imaginary part
        is NaN where the phase is unknown (:attr:`phase_known`: below the rounding floor)."""
        phase = np.angle(self.multipliers)
        if self.phase_known.size == phase.size:
            phase = np.where(self.phase_known, phase, math.nan)
        out = np.empty(phase.size, complex)
        out.real, out.imag = self.log_moduli / self.period, phase / self.period
        return out

    @property
    def stable(self) -> bool:
        """``True`` when the verdict is asymptotically stable."""
        return self.verdict == VERDICT_STABLE

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (multipliers as ``[re, im]`` pairs; non-finite numbers as ``None``)."""
        return json_ready({
            "period": self.period,
            "method": self.method,
            # a multiplier whose phase is unknown (below the rounding floor) has no value to print:
            # its modulus is in "moduli" / "log_moduli"
            "multipliers": [[float(z.real), float(z.imag)] if known else [math.nan, math.nan]
                            for z, known in zip(self.multipliers, self._known())],
            "moduli": [float(m) for m in self.moduli],
            "log_moduli": [float(v) for v in self.log_moduli],
            "spectral_radius": float(self.spectral_radius),
            "verdict": self.verdict,
            "stability_tolerance": float(self.stability_tolerance),
            "liouville_residual": float(self.liouville_residual),
            "liouville_source": self.liouville_source,
            "multiplier_liouville_residual": None
            if math.isnan(self.multiplier_liouville_residual)
            else float(self.multiplier_liouville_residual),
            "trace_integral": float(self.trace_integral),
            "error_estimate": None if math.isnan(self.error_estimate) else float(self.error_estimate),
            "noise_floor": float(self.noise_floor),
            "reliable_digits": [float(d) for d in self.reliable_digits],
            "n_steps": int(self.n_steps),
            "n_evaluations": int(self.n_evaluations),
            "elapsed": float(self.elapsed),
            "accuracy": self.accuracy,
            "phase_error_estimate": float(self.phase_error_estimate),
            "rtol": float(self.rtol),
            "certified": [bool(c) for c in self.certified],
            "all_certified": self.all_certified,
            "uncertified_reasons": [r or None for r in self.uncertified_reasons],
            "phase_known": [bool(k) for k in self.phase_known],
            "observed_order": float(self.observed_order),
            "breakpoints": [float(b) for b in self.breakpoints],
        })


# --------------------------------------------------------------------------- helpers
@dataclass(frozen=True)
class _Spectrum:
    values: np.ndarray  # complex, sorted by modulus, descending
    log_moduli: np.ndarray


def _eigvals(Phi: np.ndarray) -> np.ndarray:
    """Eigenvalues of a real square matrix (LAPACK ``dgeev`` directly: 4x faster than
    ``np.linalg.eigvals`` for the 4x4 monodromy matrix; the same routine)."""
    if Phi.dtype == np.float64 and Phi.ndim == 2:
        wr, wi, _, _, info = dgeev(Phi, compute_vl=0, compute_vr=0)
        if info == 0:
            return wr + 1j * wi
    return np.linalg.eigvals(Phi).astype(complex)


def _fro(X: np.ndarray) -> float:
    """Frobenius norm of a real matrix: ``sqrt(x . x)`` of its entries, as ``np.linalg.norm`` computes
    it, without that function's argument handling."""
    v = X.ravel()
    return math.sqrt(float(v @ v)) if v.dtype.kind == "f" else float(np.linalg.norm(X))


def _norm2(Phi: np.ndarray) -> float:
    """``||Phi||_2``, the largest singular value (LAPACK ``dgesdd`` directly for a real matrix: twice as fast
    as ``np.linalg.svd`` on a 4x4; the same routine)."""
    if Phi.dtype == np.float64 and Phi.ndim == 2 and np.isfinite(Phi).all():
        _, sv, _, info = dgesdd(Phi, compute_uv=0)
        if info == 0:
            return float(sv[0])
    return float(np.linalg.svd(Phi, compute_uv=False)[0])


def _spectrum(Phi: np.ndarray) -> _Spectrum:
    vals = _eigvals(Phi)
    logs = np.log(np.abs(vals))  # -inf for an exact zero (callers run under np.errstate)
    # descending modulus; within a conjugate pair the positive imaginary part first
    order = np.lexsort((-vals.imag, -logs))
    return _Spectrum(vals[order], logs[order])


#: ``ln eps``: multipliers below ``eps`` times the largest are rounding noise (:func:`_sort_order_pairs`).
_LOG_EPS = math.log(_EPS)

#: Largest system whose spectra are paired between refinement levels by an assignment
#: (:func:`_match`, ``O(n^3)``); larger ones are paired by sort order.
MATCH_MAX_N = 1500


def _sort_order_pairs(av: list, bv: list, la: list, lb: list) -> bool:
    """Whether ``bv[i]`` is the nearest of ``bv`` to ``av[i]`` for every ``i`` and the log moduli agree
    to 0.5 (plain Python: a handful of numbers), places where both multipliers are below
    ``eps`` times their spectrum's largest left out.

    Those are beneath the rounding floor of the formed product (``n eps ||Phi|| >= n eps rho``):
    modulus and phase are rounding noise, their rounding level (:func:`_rounding_levels`, at least
    ``10 sqrt(N)`` relative) caps their estimates at no digit, and their sort-order places pair
    them as well as any assignment would."""
    ta, tb = la[0] + _LOG_EPS, lb[0] + _LOG_EPS  # (NaN: nothing left out)
    for x, y, lx, ly in zip(av, bv, la, lb):
        if lx < ta and ly < tb:
            continue
        if not abs(lx - ly) < 0.5:
            return False
        d = abs(x - y)
        for z in bv:
            if not d <= abs(x - z):  # (NaN: not paired)
                return False
    return True


def _match(a: _Spectrum, b: _Spectrum) -> _Spectrum:
    """``b`` reordered so that ``b[i]`` is the counterpart of ``a[i]`` (two refinements of one spectrum).

    Pairing by sort order fails wherever moduli are equal or nearly so (a Hamiltonian system's
    multipliers all on the unit circle, a complex pair next to a real one): the "change" is then
    the distance between two different multipliers.  The pairing here minimises the total
    distance in the complex logarithm, ``sum_i |log a_i - log b_(pi i)|`` (relative distance in
    modulus and phase, the phase difference wrapped to ``(-pi, pi]``), by the Hungarian algorithm
    (:func:`stability.assignment.linear_assignment`).  Sort order stands when it pairs every
    multiplier with its nearest counterpart, leaving out places where both are below ``eps`` times
    their spectrum's largest (rounding noise, see :func:`_sort_order_pairs`).
    """
    n = a.values.size
    if n < 2 or n != b.values.size or n > MATCH_MAX_N:
        return b
    if n <= SMALL_N:  # a few complex numbers: plain Python is cheaper than numpy calls
        if _sort_order_pairs(a.values.tolist(), b.values.tolist(), a.log_moduli.tolist(), b.log_moduli.tolist()):
            return b
    else:
        near = np.abs(a.values[:, None] - b.values[None, :]).argmin(axis=1)
        # (as in :func:`_sort_order_pairs`: places where both are below eps of the largest left out)
        noise = ((a.log_moduli < a.log_moduli[0] + _LOG_EPS) & (b.log_moduli < b.log_moduli[0] + _LOG_EPS))
        if np.all((near == np.arange(n)) | noise) and np.all((np.abs(a.log_moduli - b.log_moduli) < 0.5) | noise):
            return b  # sort order pairs every multiplier with its nearest (and moduli agree to 50 %)
    if n <= SMALL_N:
        cost = _log_distances(a.values.tolist(), b.values.tolist(), a.log_moduli.tolist(), b.log_moduli.tolist())
        cols = [row.index(min(row)) for row in cost]
    else:
        la, lb = a.log_moduli, b.log_moduli
        finite = np.concatenate([la[np.isfinite(la)], lb[np.isfinite(lb)]])
        low = (float(finite.min()) if finite.size else 0.0) - 50.0
        la, lb = np.where(np.isfinite(la), la, low), np.where(np.isfinite(lb), lb, low)
        dphase = np.angle(a.values[:, None] * np.conj(b.values[None, :]))
        cost = np.hypot(la[:, None] - lb[None, :], np.where(np.isfinite(dphase), dphase, math.pi))
        cols = cost.argmin(axis=1).tolist()
    if sorted(cols) == list(range(n)):
        # every multiplier's nearest counterpart is a different one: that pairing is an optimal
        # assignment (each term of the sum at its row minimum), no Hungarian step needed
        if cols == list(range(n)):
            return b
    else:
        from stability.assignment import linear_assignment

        cols = linear_assignment(cost).tolist()
    return _Spectrum(b.values[cols], b.log_moduli[cols])


def _log_distances(av: list, bv: list, la: list, lb: list) -> list:
    """:func:`_match`'s cost matrix for a handful of multipliers, in plain Python: ``hypot`` of the
    difference of the log moduli (an exact zero's ``-inf`` replaced by 50 below the smallest finite
    one) and of the phase of ``a_i conj(b_j)`` (``pi`` where that is not finite), as rows."""
    finite = [x for x in la + lb if math.isfinite(x)]
    low = (min(finite) if finite else 0.0) - 50.0
    la = [x if math.isfinite(x) else low for x in la]
    lb = [x if math.isfinite(x) else low for x in lb]
    rows = []
    for x, lx in zip(av, la):
        row = []
        for y, ly in zip(bv, lb):
            d = cmath.phase(x * y.conjugate())
            row.append(math.hypot(lx - ly, d if math.isfinite(d) else math.pi))
        rows.append(row)
    return rows


def _multiplier_changes(a: _Spectrum, b: _Spectrum) -> np.ndarray:
    """Relative change of each multiplier between two refinements (paired by :func:`_match`).

    The larger of the relative change of the modulus and the change of the
    phase (radians), so that the phases of complex pairs are watched too.
    """
    b = _match(a, b)
    dmod = np.abs(np.expm1(a.log_moduli - b.log_moduli))
    dphase = np.abs(np.angle(a.values * np.conj(b.values)))
    d = np.maximum(dmod, dphase)
    return np.where(np.isfinite(d), d, np.inf)


def _phase_changes(a: _Spectrum, b: _Spectrum) -> np.ndarray:
    """Change of each multiplier's phase (radians) between two refinements (paired by :func:`_match`)."""
    b = _match(a, b)
    d = np.abs(np.angle(a.values * np.conj(b.values)))
    return np.where(np.isfinite(d), d, np.inf)


def _select_changes(a: _Spectrum, b: _Spectrum, accuracy: str) -> np.ndarray:
    """Per-multiplier relative changes of what ``accuracy`` measures (paired by :func:`_match`): the
    moduli (``"moduli"``, ``"dominant"``) or the multipliers (``"multipliers"``)."""
    if accuracy in ("moduli", "dominant"):
        b = _match(a, b)
        d = np.abs(np.expm1(a.log_moduli - b.log_moduli))
        return np.where(np.isfinite(d), d, np.inf)
    return _multiplier_changes(a, b)


def dominant_mask(log_moduli: np.ndarray, estimates: np.ndarray) -> np.ndarray:
    """The multipliers an ``accuracy="dominant"`` estimate covers (``log_moduli`` descending).

    Multiplier ``i`` (modulus ``m_i``, relative error estimate ``e_i``) is covered when
    ``m_i >= rho (1 - DOMINANT_BAND)`` (within the band of the spectral radius ``rho = m_0``)
    or when its error interval, widened by :data:`DOMINANT_SAFETY`, reaches that of ``rho``:
    ``m_i (1 + S e_i) >= rho (1 - S e_0)``.  Maths: if every uncovered multiplier's true
    modulus is below ``m_i (1 + S e_i) < rho (1 - S e_0) <= `` the true spectral radius,
    the true spectral radius is the largest true modulus of the covered ones, so the sorted
    largest modulus is in error by at most the largest covered ``e_i``: the estimate over
    the covered set bounds the spectral radius' error, and the verdict ``rho`` vs 1, even
    when the uncovered estimates miss their errors by a factor up to ``S``.  ``rho`` itself
    (index 0) is always covered.  A non-finite ``e_i`` covers ``i``.
    """
    m = np.exp(log_moduli - log_moduli[0])  # moduli relative to rho
    e = np.where(np.isfinite(estimates), estimates, np.inf)
    with np.errstate(invalid="ignore", over="ignore"):
        low = 1.0 - DOMINANT_SAFETY * e[0]
        mask = (m >= 1.0 - DOMINANT_BAND) | (m * (1.0 + DOMINANT_SAFETY * e) >= low) | ~np.isfinite(e)
    mask[0] = True
    return mask


def _estimate(changes: np.ndarray, fine: _Spectrum, factor: float, accuracy: str = "moduli") -> float:
    """Richardson estimate over moduli above ``ESTIMATE_FLOOR`` of the largest, or with
    ``accuracy="dominant"`` over :func:`dominant_mask`'s multipliers."""
    keep = fine.log_moduli >= fine.log_moduli[0] + math.log(ESTIMATE_FLOOR)
    if accuracy == "dominant":
        keep = keep & dominant_mask(fine.log_moduli, changes / factor)
        logger.debug("dominant estimate covers %d of %d multipliers", int(keep.sum()), len(keep))
    return float(changes[keep].max()) / factor


#: Safety factor on every refinement estimate.  The Magnus schemes here are symmetric
#: (time-reversible), so the global error has an expansion in even powers,
#: ``e(h) = C h^p + D h^(p+2) + ...`` (Blanes et al. 2009, Sec. 4.3); the extrapolated estimate
#: with the order observed over three levels is exact for the leading term and misses the next
#: one by its relative size, which the factor 2 covers while that term is up to the leading one
#: (and a drift of the observed order by up to 1 between levels at ``p >= 4``: ``(2^p - 1) /
#: (2^(p-1) - 1) <= 2.15``).  Measured without it: the estimate fell below the error in half of
#: the smooth literature cases, by up to 0.7 %.
ESTIMATE_SAFETY = 2.0
#: An observed order above ``p`` + this is taken for an accidental agreement of the last two
#: levels, see :func:`_extrapolated_estimate`: before the asymptotic range the two correction
#: terms ``h^(p+2)``, ``h^(p+4)`` of the even expansion can make the error fall faster than
#: ``h^p`` (measured: 8.1 for magnus6 on the controlled manipulator at 2 pi), more cannot.
ACCIDENTAL_ORDER_EXCESS = 4.0
#: Lowest order the extrapolation assumes: a change that shrinks more slowly than this over a
#: doubling (or grows) is not converging, and its estimate is the change times ``1 / (2^0.5 - 1)``.
MIN_ORDER = 0.5
#: An observed order below this fraction of the scheme's is *well below* it (``P`` or its
#: derivatives jump inside the period, or the steps do not resolve it): reported in
#: :attr:`FloquetResult.observed_order`, warned about, and the estimate uses the observed order.
LOW_ORDER_FRACTION = 0.5
#: The refinement stops when every estimate above ``rtol`` is within this factor of its
#: multiplier's rounding level (which grows with the steps: refining cannot help).
ROUNDING_STOP = 1.5
#: Changes below this many times a multiplier's rounding level (:func:`_rounding_levels`) carry
#: no order information (the levels agree to rounding).
ORDER_NOISE = 100.0


def _rounding_levels(spec: _Spectrum, norm: float, steps: int) -> np.ndarray:
    """Relative rounding level of each multiplier of a product of ``steps`` factors:
    ``10 sqrt(steps) eps ||Phi|| / |rho_i|`` (random accumulation of one rounding per factor,
    relative to the multiplier; the absolute floor of a small multiplier is set by ``||Phi||``)."""
    level = _rounding_factor(norm, steps) * np.exp(-spec.log_moduli)
    return np.where(np.isfinite(level), level, np.inf)


def _rounding_factor(norm: float, steps: int) -> float:
    """``10 sqrt(steps) eps ||Phi||``: :func:`_rounding_levels` times a multiplier's modulus."""
    return 10.0 * math.sqrt(max(steps, 1)) * _EPS * norm


def _observed_order(Ns: Sequence[int], d1: np.ndarray, d2: np.ndarray, p: float) -> np.ndarray:
    """Order ``q`` with ``d1 / d2 = (Na^-q - Nb^-q) / (Nb^-q - Nc^-q)`` for levels ``Na < Nb < Nc``.

    ``d1`` is the change between the two coarser levels, ``d2`` between the two finer ones.
    The right-hand side is increasing in ``q`` (``(Nb/Na)^q`` for equal ratios); solved by
    bisection on ``[0, 3 p]``; ``0`` where ``d2 >= d1`` (no convergence).
    """
    Na, Nb, Nc = (float(N) for N in Ns)
    ratio = np.asarray(d1, float) / np.asarray(d2, float)
    if abs(Nb / Na - Nc / Nb) <= 1e-12 * (Nc / Nb):  # equal ratios: (Nb / Na)^q
        q = np.log(ratio) / math.log(Nb / Na)
        q = np.where(ratio > 1.0, q, 0.0)
        return np.where(np.isfinite(q), np.minimum(q, 3.0 * p), 0.0)
    la, lb, lc = math.log(Na), math.log(Nb), math.log(Nc)

    def g(q):
        return (np.exp(-q * la) - np.exp(-q * lb)) / (np.exp(-q * lb) - np.exp(-q * lc))

    lo = np.full(ratio.shape, 1e-6)
    hi = np.full(ratio.shape, 3.0 * p)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        up = g(mid) < ratio
        lo = np.where(up, mid, lo)
        hi = np.where(up, hi, mid)
    q = 0.5 * (lo + hi)
    q = np.where(ratio <= g(1e-6), 0.0, q)
    return np.where(np.isfinite(ratio), q, 0.0)


@dataclass(frozen=True)
class _LevelEstimate:
    """Per-multiplier error estimates from the last two or three refinement levels."""

    estimates: np.ndarray  # relative error of what ``accuracy`` measures (incl. cluster bounds)
    phase_estimates: np.ndarray  # radians
    observed_order: float  # smallest order observed over the covered multipliers (nan: < 3 levels)
    order_checked: bool
    clusters: tuple  # ((indices...), bound, nilpotent norm) of defective / clustered groups
    rounding_limited: bool  # the cluster bounds rest on a matrix estimate at the rounding level
    noise: np.ndarray  # relative rounding level of each multiplier (:func:`_rounding_levels`)
    error: float = math.nan  # :func:`_estimate` of ``estimates`` (what ``accuracy`` covers)
    phase_error: float = math.nan  # :func:`_estimate` of ``phase_estimates``


def _two_term_error(Ns: Sequence[int], s1: np.ndarray, s2: np.ndarray, p: float) -> np.ndarray:
    """``|e(Nc)|`` of the two-term error model ``e(N) = C N^-p + D N^-(p+2)`` fitted to the *signed*
    changes ``s1 = v(Nb) - v(Na)``, ``s2 = v(Nc) - v(Nb)`` of three levels ``Na < Nb < Nc``.

    The symmetric Magnus schemes have an error expansion in even powers of the step (Blanes et al.
    2009, Sec. 4.3), so the two leading terms are determined exactly by two changes (Cramer's rule on
    ``x = C Nc^-p``, ``y = D Nc^-(p+2)``; ``e(Nc) = x + y``).  Where the coarse levels converge faster
    than ``h^p`` (the observed order above ``p + 2``: the ``h^(p+2)`` term of the other sign dominated
    them), the one-term extrapolation of the last change under-estimates the finest error and this
    does not; elsewhere it is at most the one-term value and the larger of the two is kept.
    """
    c1, c2 = _two_term_weights(Ns, p)
    return np.abs(c1 * s1 + c2 * s2)


def _two_term_weights(Ns: Sequence[int], p: float) -> tuple[float, float]:
    """``(c1, c2)`` with ``e(Nc) = x + y = c1 s1 + c2 s2`` in :func:`_two_term_error` (Cramer's rule)."""
    Na, Nb, Nc = (float(N) for N in Ns)
    A, B = Nc / Na, Nc / Nb
    a11, a12 = A**p - B**p, A ** (p + 2) - B ** (p + 2)
    a21, a22 = B**p - 1.0, B ** (p + 2) - 1.0
    det = a11 * a22 - a12 * a21
    return (a22 - a21) / det, (a11 - a12) / det


def _extrapolated_estimate(Ns: Sequence[int], d1: Optional[np.ndarray], d2: np.ndarray, p: float,
                           noise: np.ndarray, signed: Optional[tuple] = None) -> tuple[np.ndarray, np.ndarray]:
    """Error estimate of the finest level from the changes ``d1`` (coarsest pair) and ``d2`` (finest).

    ``q = min(p, observed order)`` (clipped to ``[MIN_ORDER, p]``; ``p`` where the changes are at
    the rounding level ``noise``; at most 1 when below ``LOW_ORDER_FRACTION p``), then ``ESTIMATE_SAFETY * d2 / (r2^q - 1)``, the finest error
    extrapolated from the last change; where the observed order exceeds ``p`` by more than
    :data:`ACCIDENTAL_ORDER_EXCESS` (an accidental agreement of the last two levels) the larger of
    that and the error predicted for the finest level from the change before,
    ``ESTIMATE_SAFETY * d1 / ((r1^q - 1) r2^q)``.  ``signed``: the signed changes ``(s1, s2)``
    (NaN where a change has no sign, e.g. a norm); where both changes are informative and the order
    is not well below ``p``, the estimate is at least ``ESTIMATE_SAFETY`` times the two-term model's
    error (:func:`_two_term_error`).  With two levels only, ``q = p``.  Returns ``(estimates,
    observed orders)`` (NaN where unobserved).
    """
    r2 = Ns[-1] / Ns[-2]
    if d1 is None or len(Ns) < 3:
        q = np.full(d2.shape, float(p))
        return ESTIMATE_SAFETY * d2 / (r2**p - 1.0), np.full(d2.shape, math.nan)
    r1 = Ns[-2] / Ns[-3]
    q_obs = _observed_order(Ns[-3:], d1, d2, p)
    level = ORDER_NOISE * noise
    informative = (d2 > level) & (d1 > level)
    q = np.where(informative, np.minimum(np.maximum(q_obs, MIN_ORDER), p), float(p))
    # well below the scheme's order there is no error expansion to extrapolate (a jump of P inside a
    # step: the error depends on where the jump falls in the grid, not smoothly on N): first order,
    # the order of a step across a jump, or the observed one if lower
    q = np.where(q < LOW_ORDER_FRACTION * p, np.minimum(q, 1.0), q)
    last = d2 / (r2**q - 1.0)
    # an observed order above p + 4 is no leading term of the (even) error expansion: the last two
    # levels agree by accident (the error changes sign between them), so the previous change decides
    accidental = informative & (q_obs > p + ACCIDENTAL_ORDER_EXCESS)
    if accidental.any():
        last = np.where(accidental, np.maximum(last, d1 / ((r1**q - 1.0) * r2**q)), last)
    if signed is not None:
        two = _two_term_error(Ns[-3:], signed[0], signed[1], p)
        use = informative & (q >= LOW_ORDER_FRACTION * p) & np.isfinite(two)
        last = np.where(use, np.maximum(last, two), last)
    return ESTIMATE_SAFETY * last, np.where(informative, q_obs, math.nan)


def _matrix_changes(levels: Sequence["_Solve"]) -> tuple[np.ndarray, float, Optional[float], float]:
    """``(change, d2, d1, floor)``: the finest change of the (balanced) monodromy matrix, its Frobenius
    norm and the one before (None with two levels), and the rounding level ``floor`` of the product."""
    Phi, mid = levels[-1].monodromy, levels[-2].monodromy
    norm = _fro(Phi)  # Frobenius norms: >= the 2-norms, and cheap
    # rounding of a product of N factors: one rounding per factor, accumulating like a random walk
    # (Higham 2002, Sec. 3.5: N n eps is the worst case), on the Frobenius norm (>= the 2-norm)
    floor = 2.0 * math.sqrt(levels[-1].n_steps) * _EPS * norm
    change = Phi - mid
    d1 = _fro(mid - levels[-3].monodromy) if len(levels) >= 3 else None
    return change, _fro(change), d1, floor


def _matrix_error(change: np.ndarray, d2: float, est: float, floor: float) -> tuple[np.ndarray, float, float]:
    """``(E, eta, floor)`` of :func:`_matrix_estimate` from the normwise estimate ``est``."""
    eta = float(est) if math.isfinite(est) else math.inf
    E = change * (eta / d2) if d2 > 0 and math.isfinite(eta) else np.zeros_like(change)
    return E, max(eta, floor), floor


def _matrix_estimate(levels: Sequence["_Solve"], p: float) -> tuple[np.ndarray, float, float]:
    """``(E, eta, floor)``: the estimated error matrix ``Phi_true - Phi_finest`` (balanced
    coordinates: the finest change scaled by :func:`_extrapolated_estimate`'s factor on the normwise
    changes), its 2-norm ``eta`` (at least ``floor``) and the rounding level ``floor`` of the product."""
    change, d2, d1, floor = _matrix_changes(levels)
    est, _ = _extrapolated_estimate([lv.n_steps for lv in levels], None if d1 is None else np.array([d1]),
                                    np.array([d2]), p, np.array([floor / ORDER_NOISE]))
    return _matrix_error(change, d2, float(est[0]), floor)


#: Two multipliers closer than this many times the sum of their changes over the last refinement
#: are examined as a possibly defective or clustered group (:func:`_cluster_bounds`): a Jordan
#: block of size 2 moves its eigenvalues by about ``sqrt(eta nu)`` between refinements, as far as
#: its computed pair lies apart, while first-order perturbation theory holds for eigenvalues much
#: farther apart than they move.
CLUSTER_RADIUS = 10.0


def _henrici_radius(eta: float, nu: float, m: int) -> float:
    """The ``delta > 0`` with ``1 = eta sum_{k<m} nu^k / delta^(k+1)``.

    From the proof of Henrici's theorem (Golub & Van Loan 2013, Thm. 7.2.3): for ``T = D + N``
    (``m x m``, ``N`` strictly upper triangular, ``||N|| = nu``) and ``mu`` an eigenvalue of
    ``T + E``, ``||E|| = eta``, with ``delta = min |mu - d_i|``:
    ``1 <= ||(mu - D - N)^-1|| eta <= eta sum_{k<m} nu^k / delta^(k+1)``, so ``delta`` is at most
    this root (``eta`` for ``nu = 0``; ``(eta + sqrt(eta^2 + 4 eta nu)) / 2`` for a pair).  The
    right-hand side falls with ``delta``: bisection in log space.
    """
    if not (math.isfinite(eta) and math.isfinite(nu)):
        return math.inf
    if eta <= 0.0:
        return 0.0
    if m == 2:
        return 0.5 * (eta + math.sqrt(eta * eta + 4.0 * eta * nu))

    def excess(d):
        return eta * sum(nu**k / d ** (k + 1) for k in range(m)) - 1.0

    lo, hi = eta, eta + max(nu, eta) + eta ** (1.0 / m) * max(1.0, nu) ** (1.0 - 1.0 / m) + 1.0
    try:
        while excess(hi) > 0:
            hi *= 2.0
    except OverflowError:  # a bound beyond double precision: nothing is certified
        return math.inf
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if excess(mid) > 0:
            lo = mid
        else:
            hi = mid
    return hi


def _any_near(lam: list, previous: list, keep: list) -> bool:
    """Whether two of the ``keep`` multipliers lie within :data:`CLUSTER_RADIUS` times the sum of their
    changes (``lam`` and the paired ``previous`` level) of each other: the test of :func:`_cluster_bounds`."""
    moved = [abs(a - b) for a, b in zip(lam, previous)]
    for i in range(len(lam)):
        for j in range(i + 1, len(lam)):
            if keep[i] and keep[j] and abs(lam[i] - lam[j]) <= CLUSTER_RADIUS * (moved[i] + moved[j]):
                return True
    return False


def _cluster_bounds(spec: _Spectrum, levels: Sequence["_Solve"], p: float,
                    previous: Optional[_Spectrum] = None,
                    matrix: Optional[tuple] = None) -> tuple[np.ndarray, tuple, bool]:
    """Absolute error bounds of multipliers in defective or clustered groups (NaN elsewhere).

    Which multipliers form a group: the estimated error matrix ``E`` (:func:`_matrix_estimate`)
    in the eigenvector basis, ``F = V^-1 E V``, couples eigenvalues ``i, j`` beyond first order when
    the 2x2 problem ``[[l_i + F_ii, F_ij], [F_ji, l_j + F_jj]]`` is dominated by its off-diagonal
    part, ``4 sqrt|F_ij F_ji| >= |l_i - l_j|`` (for a defective multiplier ``V`` is nearly singular
    and ``F`` large), or when the two computed eigenvalues lie within the square root of the
    rounding level of each other (a Jordan block split by rounding).  Elsewhere the Richardson
    estimate of each multiplier stands (first-order theory holds).

    Bound of a group (Henrici's theorem applied to it, Golub & Van Loan 2013, Thm. 7.2.3): with the
    complex Schur form of ``Phi`` reordered so that the group's ``m`` eigenvalues lead,
    ``T11 = D + N`` (``N`` strictly upper triangular, ``nu = ||N||_2``, the group's departure
    from normality), a perturbation of norm ``eta_g`` moves them by at most the ``delta`` of
    :func:`_henrici_radius` (``~ sqrt(eta_g nu)`` for a pair, ``eta_g`` when ``nu = 0``) from the
    computed ones (plus the group's spread: the bound is to *some* computed eigenvalue of the
    group).  ``eta_g =
    ||E11|| + ||T12|| ||E21|| / gap + floor`` is the part of ``E`` (in the same Schur basis) that
    acts on the group, the coupling to the other eigenvalues through ``T12`` (``gap`` = their
    distance from the group) and the rounding level.  For a semisimple double multiplier
    ``nu ~ 0`` and the bound is first order; for a Jordan block it is the square root.
    ``matrix``: :func:`_matrix_estimate`'s ``(E, eta, floor)`` when the caller has it already.
    Returns ``(bounds, groups, rounding_limited)``.
    """
    n = spec.values.size
    bounds = np.full(n, math.nan)
    if n < 2 or len(levels) < 2 or n > MATCH_MAX_N:
        return bounds, (), False
    lam = spec.values
    previous = _match(spec, levels[-2].spectrum) if previous is None else previous
    if n <= SMALL_N:  # the common case, decided in plain Python (a handful of numbers)
        lams, logs = lam.tolist(), spec.log_moduli.tolist()
        if matrix is not None:  # only multipliers the estimate covers can form a group (below)
            top, low = logs[0] + math.log(ESTIMATE_FLOOR), 100.0 * matrix[2]
            keep = [lg >= top and abs(z) > low for z, lg in zip(lams, logs)]
        else:
            keep = [True] * n
        if not _any_near(lams, previous.values.tolist(), keep):
            return bounds, (), False
    dist = np.abs(lam[:, None] - lam[None, :])
    moved = np.abs(lam - previous.values)  # change over the last refinement
    near = dist <= CLUSTER_RADIUS * (moved[:, None] + moved[None, :])
    diag = np.arange(n)
    near[diag, diag] = False
    if not near.any():
        return bounds, (), False
    E, eta, floor = _matrix_estimate(levels, p) if matrix is None else matrix
    Phi = levels[-1].monodromy
    # only multipliers the estimate covers: modulus >= ESTIMATE_FLOOR of the largest, above rounding
    covered = (spec.log_moduli >= spec.log_moduli[0] + math.log(ESTIMATE_FLOOR)) & (np.abs(lam) > 100.0 * floor)
    near &= covered[:, None] & covered[None, :]
    if not near.any():
        return bounds, (), False
    from scipy.linalg import eig, schur

    w, VL, V = eig(Phi, left=True, right=True)
    order = [int(np.argmin(np.abs(w - z))) for z in lam]
    V, VL = V[:, order], VL[:, order]
    with np.errstate(all="ignore"):
        kappa = 1.0 / np.abs(np.sum(np.conj(VL) * V, axis=0))  # unit vectors: 1 / |y^H x|
    kappa = np.where(np.isfinite(kappa), kappa, np.inf)
    try:
        with np.errstate(all="ignore"):
            F = np.linalg.solve(V, E.astype(complex) @ V)
        F = np.where(np.isfinite(F), F, np.inf)
    except np.linalg.LinAlgError:
        F = np.full((n, n), np.inf, complex)
    with np.errstate(invalid="ignore", over="ignore"):
        coupled = 4.0 * np.sqrt(np.abs(F) * np.abs(F.T)) >= dist
    # first-order discs at the rounding level overlap: a Jordan block split by rounding
    coupled |= 4.0 * (kappa[:, None] + kappa[None, :]) * floor >= dist
    coupled &= near
    np.fill_diagonal(coupled, False)
    if not coupled.any():
        return bounds, (), False
    label = np.arange(n)
    for _ in range(n):  # connected components of "coupled"
        new = np.minimum(label, np.min(np.where(coupled, label[None, :], n), axis=1))
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    groups = []
    limited = False
    for g in np.unique(label):
        idx = np.flatnonzero(label == g)
        if idx.size < 2:
            continue
        centre = lam[idx]
        spread = float(np.max(np.abs(centre[:, None] - centre[None, :])))
        others = np.setdiff1d(np.arange(n), idx)
        gap = float(np.min(dist[np.ix_(idx, others)])) if others.size else math.inf
        reach = max(min(0.5 * gap, 2.0 * spread + 1e-300), 1e-300)

        def select(z, centre=centre, reach=reach):
            return bool(np.min(np.abs(z - centre)) <= reach)

        m = idx.size
        try:
            T, Z, sdim = schur(Phi.astype(complex), output="complex", sort=select)
        except (ValueError, np.linalg.LinAlgError):
            sdim = -1
        if sdim != m:  # the reordering did not isolate the group: Henrici on the whole matrix
            T, Z = schur(Phi.astype(complex), output="complex")
            m, eta_g = n, eta
        else:
            Eh = Z.conj().T @ E @ Z
            eta_g = float(np.linalg.norm(Eh[:m, :m], 2)) + floor
            if others.size and gap > 0:
                eta_g += float(np.linalg.norm(T[:m, m:], 2)) * float(np.linalg.norm(Eh[m:, :m], 2)) / gap
        nu = float(np.linalg.norm(np.triu(T[:m, :m], 1), 2))
        b = spread + _henrici_radius(eta_g, nu, m)
        bounds[idx] = b
        groups.append((tuple(int(i) for i in idx), float(b), nu))
        limited |= eta_g <= 10.0 * floor
    return bounds, tuple(groups), limited


def _level_estimates(levels: Sequence["_Solve"], p: float, accuracy: str) -> _LevelEstimate:
    """Per-multiplier estimates of the finest of ``levels`` (ascending step counts, >= 2 of them).

    Rules, each a separate term (the largest wins):

    1. The multipliers of the levels are paired by :func:`_match`, not by sort order.
    2. Their changes are extrapolated with the order observed over the last three levels when it
       is below the scheme's (:func:`_extrapolated_estimate`), times :data:`ESTIMATE_SAFETY`.
    3. Defective or clustered multipliers get the bound of :func:`_cluster_bounds`.
    4. Nothing is claimed below the rounding level of the product (:func:`_rounding_levels`).
    """
    fine = levels[-1]
    spec = fine.spectrum
    Ns = [lv.n_steps for lv in levels[-3:]]
    if spec.values.size <= SMALL_N and len(levels) >= 3 and accuracy != "dominant" \
            and Ns[1] * Ns[1] == Ns[0] * Ns[2]:
        small = _level_estimates_small(levels, p, accuracy)
        if small is not None:
            return small
    norm = _fro(fine.monodromy)  # Frobenius: >= ||Phi||_2
    noise = _rounding_levels(spec, norm, fine.n_steps)

    mid = _match(spec, levels[-2].spectrum)
    three = len(levels) >= 3
    # the changes of both pairs of levels at once: rows (fine, mid) - (mid, coarse)
    if three:
        coarse = _match(mid, levels[-3].spectrum)
        va, vb = np.array((spec.values, mid.values)), np.array((mid.values, coarse.values))  # np.stack, cheaper
        la, lb = np.array((spec.log_moduli, mid.log_moduli)), np.array((mid.log_moduli, coarse.log_moduli))
    else:
        va, vb, la, lb = spec.values[None], mid.values[None], spec.log_moduli[None], mid.log_moduli[None]
    smod = np.expm1(la - lb)  # signed: rows (fine - mid, mid - coarse)
    sph = np.angle(va * np.conj(vb))
    # rows: the moduli, the phases, the normwise change of the matrix (for the cluster bounds' error
    # matrix, :func:`_matrix_estimate`), each (pairs, n); with accuracy="multipliers" the estimate of
    # a multiplier is the larger of its modulus' and its phase's
    change, m2, m1, floor = _matrix_changes(levels)
    d = np.empty((smod.shape[0], 3, smod.shape[1]))
    d[:, 0], d[:, 1] = np.abs(smod), np.abs(sph)
    d[0, 2] = m2
    if three:
        d[1, 2] = m1
    d[~np.isfinite(d)] = np.inf
    d2 = d[0]
    d1 = d[1] if three else None
    noises = np.empty((3, noise.size))
    noises[0] = noises[1] = noise
    noises[2] = floor / ORDER_NOISE
    signed = None
    if three:
        s = np.full((2, 3, noise.size), math.nan)
        s[:, 0], s[:, 1] = smod, sph
        signed = (s[1], s[0])
    both, q_both = _extrapolated_estimate(Ns, d1, d2, p, noises, signed)
    est, phase, q_obs = both[0], both[1], q_both[0]
    if accuracy not in ("moduli", "dominant"):
        est = np.maximum(est, phase)
        q_obs = np.fmin(q_obs, q_both[1])
    matrix = _matrix_error(change, m2, float(both[2][0]), floor)
    bounds, groups, limited = _cluster_bounds(spec, levels[-3:], p, mid, matrix)
    if groups:
        rel = bounds * np.exp(-spec.log_moduli)
        has = np.isfinite(bounds)
        est = np.where(has, np.maximum(est, rel), est)
        phase = np.where(has, np.maximum(phase, rel), phase)
    est = np.maximum(np.where(np.isfinite(est), est, np.inf), noise)
    phase = np.maximum(np.where(np.isfinite(phase), phase, np.inf), noise)
    keep = spec.log_moduli >= spec.log_moduli[0] + math.log(ESTIMATE_FLOOR)
    observed = q_obs[keep & np.isfinite(q_obs)]
    order = float(observed.min()) if observed.size else math.nan
    return _LevelEstimate(est, phase, order, len(levels) >= 3, groups, limited, noise,
                          _estimate(est, spec, 1.0, accuracy), _estimate(phase, spec, 1.0))


def _level_estimates_small(levels: Sequence["_Solve"], p: float, accuracy: str) -> Optional[_LevelEstimate]:
    """:func:`_level_estimates` for a handful of multipliers, three levels in one ratio, in plain Python.

    The same rules and the same numbers (to rounding: Python's ``math`` functions for numpy's), at a
    fraction of the cost of the numpy calls on a few numbers.  Returns None where the general path
    must decide: a non-finite multiplier or change (or one beyond the float range of ``math``), or a
    possibly defective or clustered group.
    """
    try:
        return _level_estimates_plain(levels, p, accuracy)
    except (OverflowError, ValueError, ZeroDivisionError):
        return None


def _level_estimates_plain(levels: Sequence["_Solve"], p: float, accuracy: str) -> Optional[_LevelEstimate]:
    """The body of :func:`_level_estimates_small` (``math`` raises where numpy gives inf)."""
    coarsest, middle, fine = levels[-3:]
    spec = fine.spectrum
    mid = _match(spec, middle.spectrum)
    coarse = _match(mid, coarsest.spectrum)
    vf, vm, vc = spec.values.tolist(), mid.values.tolist(), coarse.values.tolist()
    lf, lm, lc = spec.log_moduli.tolist(), mid.log_moduli.tolist(), coarse.log_moduli.tolist()
    finite = math.isfinite
    if not all(finite(x) for x in lf + lm + lc):
        return None
    Na, Nb, Nc = (lv.n_steps for lv in levels[-3:])
    factor = _rounding_factor(_fro(fine.monodromy), Nc)  # :func:`_rounding_levels` on a list
    noise = [v if finite(v) else math.inf for v in (factor * math.exp(-x) for x in lf)]
    change, m2, m1, floor = _matrix_changes(levels)
    both_phases = accuracy not in ("moduli", "dominant")
    rows = []  # per multiplier: signed changes (fine - mid, mid - coarse) of the modulus and the phase
    for a, b, c, la, lb, lcc in zip(vf, vm, vc, lf, lm, lc):
        rows.append((math.expm1(la - lb), math.expm1(lb - lcc),
                     cmath.phase(a * b.conjugate()), cmath.phase(b * c.conjugate())))
    if not all(finite(x) for row in rows for x in row) or not (finite(m2) and finite(m1)):
        return None
    log_r = math.log(Nb / Na)
    r = Nc / Nb
    w1, w2 = _two_term_weights((Na, Nb, Nc), p)  # the two-term model of :func:`_two_term_error`

    def extrapolate(s2: float, s1: float, level: float, signed: bool = True) -> tuple[float, float]:
        """:func:`_extrapolated_estimate` of one change (equal ratios ``r``): ``(estimate, observed order)``."""
        d2, d1 = abs(s2), abs(s1)
        ratio = d1 / d2 if d2 > 0 else math.inf
        q_obs = math.log(ratio) / log_r if ratio > 1.0 else 0.0
        q_obs = min(q_obs, 3.0 * p) if finite(q_obs) else 0.0
        informative = d2 > level and d1 > level
        q = min(max(q_obs, MIN_ORDER), p) if informative else float(p)
        if q < LOW_ORDER_FRACTION * p:
            q = min(q, 1.0)
        rq = r**q
        last = d2 / (rq - 1.0)
        if informative and q_obs > p + ACCIDENTAL_ORDER_EXCESS:
            last = max(last, d1 / ((rq - 1.0) * rq))
        if signed and informative and q >= LOW_ORDER_FRACTION * p:
            two = abs(w1 * s1 + w2 * s2)
            last = max(last, two)
        return ESTIMATE_SAFETY * last, (q_obs if informative else math.nan)

    est, phase, q_obs = [], [], []
    for (m2_, m1_, p2_, p1_), nz in zip(rows, noise):
        e, q = extrapolate(m2_, m1_, ORDER_NOISE * nz)
        f, qf = extrapolate(p2_, p1_, ORDER_NOISE * nz)
        if both_phases:
            e = max(e, f)
            q = qf if not finite(q) else (q if not finite(qf) else min(q, qf))
        est.append(max(e, nz))
        phase.append(max(f, nz))
        q_obs.append(q)
    matrix_est, _ = extrapolate(m2, m1, floor, signed=False)
    matrix = _matrix_error(change, m2, matrix_est, floor)
    bounds, groups, limited = _cluster_bounds(spec, levels[-3:], p, mid, matrix)
    if groups:
        return None
    top = lf[0] + math.log(ESTIMATE_FLOOR)
    keep = [x >= top for x in lf]
    observed = [q for q, k in zip(q_obs, keep) if k and finite(q)]
    return _LevelEstimate(np.array(est), np.array(phase), min(observed) if observed else math.nan, True, (),
                          False, np.array(noise), max(e for e, k in zip(est, keep) if k),
                          max(f for f, k in zip(phase, keep) if k))


def _trace_integral(P: Any, wrapped: PeriodicMatrixFunction, period: float) -> float:
    closed_form = getattr(P, "trace_integral", None)
    if callable(closed_form):
        return float(closed_form())
    K = TRACE_MIN_POINTS // 2
    tr = np.trace(wrapped.evaluate(np.arange(K) * (period / K)), axis1=1, axis2=2)
    total, abs_total = float(np.sum(tr)), float(np.sum(np.abs(tr)))
    integral = total * period / K
    while K < TRACE_POINTS:
        new = np.trace(wrapped.evaluate((np.arange(K) + 0.5) * (period / K)), axis1=1, axis2=2)
        total += float(np.sum(new))
        abs_total += float(np.sum(np.abs(new)))
        K *= 2
        previous, integral = integral, total * period / K
        if abs(integral - previous) <= TRACE_RTOL * abs_total * period / K:
            break
    return integral


def _verdict(rho: float, tol: float) -> str:
    """The verdict rule of :mod:`stability.verdict` on the spectral radius and its band ``tol``."""
    return verdict_band(rho, tol)


def _log_abs_det(matrices: np.ndarray) -> float:
    sign, logdet = np.linalg.slogdet(matrices)
    if np.any(sign == 0):
        return -math.inf
    return float(np.sum(logdet))


# --------------------------------------------------------------------------- methods
class FloquetError(ArithmeticError):
    """The monodromy matrix cannot be computed to the requested standard (one clear line says why)."""


class _Unresolved(Exception):
    """A propagation whose sub-intervals do not resolve ``P`` (or that overflowed)."""

    def __init__(self, message: str, *, genuine_overflow: bool = False) -> None:
        super().__init__(message)
        self.genuine_overflow = genuine_overflow


@dataclass(frozen=True)
class _Propagation:
    monodromy: np.ndarray
    spectrum: _Spectrum
    log_abs_det: float
    n_steps: int
    n_evaluations: int
    error_estimate: float
    changes: Optional[np.ndarray]  # per-multiplier relative error estimate of the result
    factors: Optional[np.ndarray] = None  # sub-interval propagators of the final solve, if kept
    phase_error_estimate: float = math.nan  # largest phase change estimate (radians), reported
    companions: tuple = ()  # (n_steps, monodromy) of the N / 3^l midpoint rules from the same factors
    observed_order: float = math.nan  # smallest order observed over three levels (nan: not observed)
    order_checked: bool = False  # the estimate rests on three levels
    clusters: tuple = ()  # defective / clustered groups: ((indices), absolute bound, nilpotent norm)
    at_cap: bool = False  # the refinement stopped before meeting rtol (step limit or rounding)
    noise_levels: Optional[np.ndarray] = None  # relative rounding level per multiplier
    scheme_order: float = math.nan


@dataclass(frozen=True)
class _Solve:
    n_steps: int
    monodromy: np.ndarray
    spectrum: _Spectrum
    log_abs_det: float
    factors: Optional[np.ndarray]
    #: the companion solve with ``N / 3`` sub-intervals (magnus2, see :func:`_third_companion`)
    third: Optional["_Solve"] = None


#: First sub-interval count of the adaptive factor methods.  Magnus schemes
#: integrate frozen oscillations exactly, so the count is chosen from the
#: accuracy actually reached (a pilot pair ``N, 2N`` and the error model
#: ``err ~ C N^-p``), not from the fastest oscillation of ``P``.
INITIAL_STEPS = 16
#: The refinement aims at ``SAFETY * rtol`` so that the certified estimate of
#: the refined solve lands below ``rtol`` in one pass.
SAFETY = 0.25
#: Largest growth of the sub-interval count in one refinement pass (the
#: Richardson estimate with ratio ``r`` divides by ``r^p - 1``; a bounded
#: ratio keeps it from resting on the asymptotic model alone).
MAX_REFINE_RATIO = 4.0
#: A refinement pass is trusted only if the pair it forms measures the
#: coarser solve's error within this factor of what the previous pair
#: predicted for it (the observed order agrees with the scheme's).
CONSISTENCY = 4.0
#: A sub-interval is *unresolved* when the commutator part of its Magnus
#: exponent, ``||Omega_k - h Pbar_k||_1``, exceeds this: it then changes the
#: propagator by up to ``e^10``, i.e. it is no correction any more and the
#: truncated series means nothing (it overflows for coarse steps and stiff P).
COMMUTATOR_LIMIT = 10.0
#: The adaptive refinement starts where the commutator part is about this
#: (the truncated series is then a small correction; see :func:`_start_steps`).
START_COMMUTATOR = 0.1
#: Memory allowed for the stacks of ``(N, n, n)`` work arrays of one solve.
MEMORY_LIMIT = 1.5e9
#: Number of ``(N, n, n)``-sized work arrays alive at once in a solve (P at the
#: Gauss points, exponents, commutators, Pade terms).
WORK_ARRAYS = 12
#: Companion solves ``N / 3, N / 9`` formed from the factors of a fixed-``N`` magnus2 solve
#: (see :func:`_third_companion`; levels as far as ``3^l`` divides ``N``).
COMPANION_LEVELS = 2
#: Memory for the work arrays of one chunk of a streamed solve (systems larger than
#: ``SMALL_N`` whose full stack of work arrays would exceed this are propagated in
#: chunks of consecutive sub-intervals, so that memory is ``O(n^2)`` in ``N``; the
#: chunks stay large enough that the per-call cost of evaluating ``P`` is shared).
CHUNK_MEMORY = 4.0e8
#: ``T * ||P||`` (balanced) beyond which the period is too long for double precision:
#: ``ln rho = T lambda`` carries an absolute rounding error ``eps T |lambda|``,
#: so at 1e12 not even the first digits of the phases are left (and moduli
#: like ``exp(T lambda)`` overflow long before).
PERIOD_SCALE_LIMIT = 1e12


def _quadrature_mean(scheme: MagnusScheme, Pg: np.ndarray) -> np.ndarray:
    """Gauss-Legendre mean of ``P`` over each sub-interval (the 2nd-order part of ``Omega_k / h``)."""
    if scheme.order == 2:
        return Pg[:, 0]
    if scheme.order == 4:
        return 0.5 * (Pg[:, 0] + Pg[:, 1])
    return (5.0 * Pg[:, 0] + 8.0 * Pg[:, 1] + 5.0 * Pg[:, 2]) / 18.0


#: Sub-intervals probed for the commutator test before a full solve (cheap
#: rejection of step counts far too coarse for a stiff, fast ``P``) ...
PROBE_INTERVALS = 8
#: ... when the full solve is large (``N n^2`` above this).
PROBE_WORK = 65536
#: Systems up to this size use matrix-major stacks ``(n, n, N)`` and Taylor
#: exponentials (:func:`_magnus_solve_small`): for tiny matrices the batched
#: BLAS calls and LAPACK solves of the ``(N, n, n)`` layout cost more than the
#: arithmetic.
SMALL_N = 8


def _commutator_limit(scheme: MagnusScheme, Om: np.ndarray, Pg: np.ndarray, h: float, N: int) -> None:
    """Raise :class:`_Unresolved` if the commutator part of an exponent exceeds :data:`COMMUTATOR_LIMIT`."""
    with np.errstate(over="ignore", invalid="ignore"):
        corr = float(np.abs(Om - h * _quadrature_mean(scheme, Pg)).sum(axis=1).max())
    if not corr <= COMMUTATOR_LIMIT:  # also catches NaN
        raise _Unresolved(
            f"{scheme.name}: the commutator terms of the Magnus exponent reach {corr:.3g} "
            f"with {N} sub-intervals (limit {COMMUTATOR_LIMIT:g}): the steps do not resolve P"
        )


def _check_commutators(scheme: MagnusScheme, wrapped: PeriodicMatrixFunction, intervals: np.ndarray,
                       h: float, N: int) -> None:
    """:func:`_commutator_limit` on the given sub-intervals only."""
    nodes = np.asarray(scheme.nodes)
    n = wrapped.n
    times = (intervals[:, None] + nodes[None, :]) * h
    Pg = wrapped.evaluate(times.ravel()).reshape(len(intervals), len(nodes), n, n)
    with np.errstate(over="ignore", invalid="ignore"):
        Om = magnus_exponents(scheme, Pg, h)
    _commutator_limit(scheme, Om, Pg, h, N)


def _memory_check(scheme: MagnusScheme, N: int, n: int) -> None:
    """Raise :class:`_Unresolved` if ``N`` sub-intervals of ``n x n`` need more than :data:`MEMORY_LIMIT`."""
    need = WORK_ARRAYS * len(scheme.nodes) * N * n * n * 8.0
    if need > MEMORY_LIMIT:
        raise _Unresolved(
            f"{scheme.name} would need {N} sub-intervals of {n}x{n} matrices "
            f"(~{need / 1e9:.1f} GB of work arrays, limit {MEMORY_LIMIT / 1e9:.1f} GB)",
            genuine_overflow=False,
        )


def _stream_chunk(scheme: MagnusScheme, n: int) -> int:
    """Sub-intervals per chunk of a streamed solve: the work arrays of one chunk within :data:`CHUNK_MEMORY`."""
    return max(1, int(CHUNK_MEMORY // (WORK_ARRAYS * len(scheme.nodes) * n * n * 8.0)))


def _third_companion(scheme: MagnusScheme, N: int, n: int) -> bool:
    """Whether a fixed-``N`` solve also forms the ``N / 3`` solve from its own factors.

    The exponential midpoint rule with ``N / 3`` sub-intervals of length ``3 h``
    samples ``P`` at ``(3 j + 3/2) h``, the midpoint of fine sub-interval
    ``3 j + 1``, and ``expm(3 h P) = expm(h P)^3``: its factors are the cubes of
    every third fine factor, so the pair ``(N, N / 3)`` of the step-doubling
    (here step-tripling) estimate costs two matrix products per coarse factor
    instead of ``N / 2`` more exponentials.  Large systems only (``n > SMALL_N``),
    where the exponentials dominate.
    """
    return scheme.order == 2 and n > SMALL_N and N % 3 == 0 and N >= 3


def _ladder_levels(N: int, levels: int) -> int:
    """The largest ``L <= levels`` with ``3^L`` dividing ``N`` (companions ``N / 3, ..., N / 3^L``)."""
    L = 0
    while L < levels and N % 3 ** (L + 1) == 0:
        L += 1
    return L


def _cubes(E: np.ndarray) -> np.ndarray:
    """Factors of the ``N / 3`` midpoint rule, ``C_j = E_{3j+1}^3``, from ``N`` factors (a multiple of 3)."""
    mid = E[1::3]
    return mid @ mid @ mid


def _companions(E: np.ndarray, Om: np.ndarray, levels: int) -> list[tuple[np.ndarray, float]]:
    """``(product, sum of traces)`` of the ``N / 3^l`` midpoint rules, ``l = 1 .. levels``, from ``N`` factors
    (``N`` a multiple of ``3^levels``; the exponent of a level-``l`` factor is ``3^l`` times a fine one)."""
    out = []
    F, Ol = E, Om
    for level in range(1, levels + 1):
        F, Ol = _cubes(F), Ol[1::3]
        out.append((ordered_product(F), 3.0**level * float(np.sum(np.trace(Ol, axis1=1, axis2=2)))))
    return out


def _chain(N: int, companions: list[tuple[np.ndarray, float]]) -> Optional["_Solve"]:
    """The companions as a chain of :class:`_Solve` (``N / 3`` with its ``third`` = ``N / 9`` ...)."""
    solve = None
    for level in range(len(companions), 0, -1):
        Phi, log_det = companions[level - 1]
        solve = _Solve(N // 3**level, Phi, _spectrum(Phi), log_det, None, solve)
    return solve


class _BlockExpmTarget:
    """``P`` (wrapped) whose Magnus exponents are nearly block diagonal over ``blocks``
    (contiguous sizes): the large factors use :func:`~stability.expm.expm_near_block_diagonal`,
    falling back to :func:`~stability.expm.expm_stack` (``scipy.linalg.expm``) per factor where
    it refuses; ``exponentials`` / ``fallbacks`` count them (logged by :func:`floquet`)."""

    def __init__(self, target: Any, blocks: tuple) -> None:
        self.target = target
        self.period = target.period
        self.n = target.n
        self.expm_blocks = blocks
        self.exponentials = 0
        self.fallbacks = 0
        self.reasons: dict = {}

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        return self.target.evaluate(times)

    def __call__(self, t: float) -> np.ndarray:
        return self.target(t)


#: Smallest system for which :class:`_BlockExpmTarget` block-diagonalises its factors: below,
#: ``scipy.linalg.expm`` is cheaper (single link, CPU ms per exponential, benchmarks/expm_speed.py:
#: 132 states 3.8 scipy vs 5.6 block, 260 states 20.5 vs 10.3).
BLOCK_EXPM_MIN_N = 200


def _factors(Om: np.ndarray, wrapped: Any) -> np.ndarray:
    """``expm`` of every exponent of the stack: :func:`expm_stack`, or by block
    diagonalisation with a per-factor fallback for a :class:`_BlockExpmTarget` of at least
    :data:`BLOCK_EXPM_MIN_N` states."""
    blocks = getattr(wrapped, "expm_blocks", None)
    if blocks is None or Om.shape[-1] < BLOCK_EXPM_MIN_N or not np.isfinite(Om).all():
        return expm_stack(Om)
    E = np.empty_like(Om)
    for k in range(Om.shape[0]):
        r = expm_near_block_diagonal(Om[k], blocks)
        wrapped.exponentials += 1
        if r.ok:
            E[k] = r.matrix
        else:
            wrapped.fallbacks += 1
            key = r.reason.split(" (")[0]
            wrapped.reasons[key] = wrapped.reasons.get(key, 0) + 1
            E[k] = expm_stack(Om[k:k + 1])[0]
    return E


def _magnus_solve(
    scheme: MagnusScheme, wrapped: PeriodicMatrixFunction, period: float, N: int, keep_factors: bool,
    strict: bool = True, third: int = 0,
) -> _Solve:
    """One propagation with ``N`` sub-intervals; raises :class:`_Unresolved` if it means nothing.

    ``third = L > 0`` (magnus2, ``n > SMALL_N``): also the companion solves with
    ``N / 3, ..., N / 3^L`` sub-intervals from the same factors
    (:func:`_third_companion`), as far as ``3^l`` divides ``N``, chained in
    ``_Solve.third``.

    ``strict=False`` (a step count fixed by the caller) skips the
    :data:`COMMUTATOR_LIMIT` test and fails only on overflow.  With a fixed
    step count (``strict=False``), large systems whose ``N`` work arrays exceed
    :data:`CHUNK_MEMORY` are propagated in chunks (:func:`_magnus_solve_streamed`)
    unless the factors are to be kept; the adaptive refinement keeps
    :data:`MEMORY_LIMIT` as its limit of effort (a stiff, fast system that no
    step count resolves fails at the limit instead of refining to ``max_steps``).
    """
    n = wrapped.n
    third = _ladder_levels(N, int(third)) if _third_companion(scheme, N, n) else 0
    if not strict and not keep_factors and n > SMALL_N and N > _stream_chunk(scheme, n):
        return _magnus_solve_streamed(scheme, wrapped, period, N, strict, _stream_chunk(scheme, n), third)
    _memory_check(scheme, N, n)
    h = period / N
    nodes = np.asarray(scheme.nodes)
    if strict and scheme.order > 2 and N * n * n > PROBE_WORK:
        # cheap probe on a few sub-intervals spread over the period before the full stack
        probe = np.unique(np.linspace(0, N - 1, PROBE_INTERVALS).astype(int))
        _check_commutators(scheme, wrapped, probe, h, N)
    times = (np.arange(N)[:, None] + nodes[None, :]) * h
    if n <= SMALL_N:
        return _magnus_solves_small(scheme, wrapped, period, [N], keep_factors, strict)[0]
    Pg = wrapped.evaluate(times.ravel()).reshape(N, len(nodes), n, n)
    with np.errstate(over="ignore", invalid="ignore"):
        Om = magnus_exponents(scheme, Pg, h)
        if strict and scheme.order > 2:
            _commutator_limit(scheme, Om, Pg, h, N)
        E = _factors(Om, wrapped)
        _check_factors(E, scheme, N, lambda: float(np.abs(Om).sum(axis=1).max()))
        Phi = ordered_product(E)
        _check_monodromy(Phi, scheme)
    log_det = float(np.sum(np.trace(Om, axis1=1, axis2=2)))
    companion = _chain(N, _companions(E, Om, third)) if third else None
    return _Solve(N, Phi, _spectrum(Phi), log_det, E if keep_factors else None, companion)


def _check_factors(E: np.ndarray, scheme: MagnusScheme, N: int, h_norm: Callable[[], float]) -> None:
    """Raise :class:`_Unresolved` (a genuine overflow) if a sub-interval propagator is not finite;
    ``h_norm()`` gives the largest ``h ||P||`` for the message (evaluated only then)."""
    if not np.isfinite(E).all():
        raise _Unresolved(
            f"{scheme.name}: a sub-interval propagator overflowed with {N} sub-intervals "
            f"(h*||P|| up to {h_norm():.3g})",
            genuine_overflow=True,
        )


def _check_monodromy(Phi: np.ndarray, scheme: MagnusScheme) -> None:
    """Raise :class:`_Unresolved` (a genuine overflow) if the (partial) monodromy is not finite."""
    if not np.isfinite(Phi).all():
        raise _Unresolved(
            f"{scheme.name}: the monodromy matrix overflowed (solutions grow beyond 1e308 "
            f"within one period)",
            genuine_overflow=True,
        )


def _magnus_solve_streamed(
    scheme: MagnusScheme, wrapped: PeriodicMatrixFunction, period: float, N: int, strict: bool, chunk: int,
    third: int = 0,
) -> _Solve:
    """:func:`_magnus_solve` with ``O(chunk n^2)`` memory: the factors of ``chunk`` consecutive sub-intervals
    are formed, multiplied (pairwise) into one and applied to the running product ``Phi``, then dropped.

    Maths: the same factors ``E_k = expm(Omega_k)`` and the same product
    ``Phi = E_N ... E_1`` as the stored solve, associated differently:
    ``Phi = (E_N ... E_{N-c+1}) ... (E_c ... E_1)``.  Each association of a
    product of ``N`` factors ``n x n`` is exact up to the first-order rounding
    bound ``|fl(Phi) - Phi| <= (N - 1) n eps |E_N| ... |E_1|`` (elementwise,
    Higham 2002, Sec. 3.5), so the two results differ by at most twice that
    (``tests/test_floquet_streamed.py`` checks it).
    """
    n = wrapped.n
    h = period / N
    nodes = np.asarray(scheme.nodes)
    q = len(nodes)
    third = int(third)
    if third:
        g = 3**third
        chunk = max(g, chunk - chunk % g)  # whole groups of 3^L in every chunk
    Phi = np.eye(n)
    ladder = [[np.eye(n), 0.0] for _ in range(third)]
    log_det = 0.0
    om_max = 0.0
    for start in range(0, N, chunk):
        idx = np.arange(start, min(N, start + chunk))
        times = (idx[:, None] + nodes[None, :]) * h
        Pg = wrapped.evaluate(times.ravel()).reshape(idx.size, q, n, n)
        with np.errstate(over="ignore", invalid="ignore"):
            Om = magnus_exponents(scheme, Pg, h)
            if strict and scheme.order > 2:
                _commutator_limit(scheme, Om, Pg, h, N)
            del Pg
            om_max = max(om_max, float(np.abs(Om).sum(axis=1).max()))
            log_det += float(np.sum(np.trace(Om, axis1=1, axis2=2)))
            E = _factors(Om, wrapped)
            for rung, (product, traces) in zip(ladder, _companions(E, Om, third)):
                rung[0] = product @ rung[0]
                rung[1] += traces
            del Om
            _check_factors(E, scheme, N, lambda: om_max)
            Phi = ordered_product(E) @ Phi
            del E
            _check_monodromy(Phi, scheme)
    logger.debug("%s: %d sub-intervals of %dx%d streamed in chunks of %d", scheme.name, N, n, n, chunk)
    companion = _chain(N, [(p, t) for p, t in ladder]) if third else None
    return _Solve(N, Phi, _spectrum(Phi), log_det, None, companion)


@functools.lru_cache(maxsize=64)
def _gauss_times(nodes: tuple, period: float, Ns: tuple) -> np.ndarray:
    """Gauss points of ``N`` equal sub-intervals of ``[0, period]`` for each ``N`` in ``Ns``, concatenated
    (cached: a loop over gains or parameters asks for the same points again; read-only)."""
    node = np.asarray(nodes)
    times = np.concatenate([((np.arange(N)[:, None] + node[None, :]) * (period / N)).ravel() for N in Ns])
    times.flags.writeable = False
    return times


@functools.lru_cache(maxsize=64)
def _step_lengths(period: float, Ns: tuple) -> Any:
    """The step length of every sub-interval of the levels ``Ns`` of :func:`_gauss_times` (a float for
    one level; cached like the points, read-only)."""
    if len(Ns) == 1:
        return period / Ns[0]
    h = np.repeat([period / N for N in Ns], Ns)
    h.flags.writeable = False
    return h


def _magnus_solves_small(
    scheme: MagnusScheme, wrapped: PeriodicMatrixFunction, period: float, Ns: list[int], keep_factors: bool,
    strict: bool, optional_first: bool = False,
) -> list[_Solve]:
    """:func:`_magnus_solve` for ``n <= SMALL_N``, for several step counts in one batch.

    Matrix-major stacks ``(n, n, sum(Ns))``: one evaluation of ``P``, one
    exponent and one exponential pass for all the solves (the step length is
    a vector along the stack), then one product per solve.  The exponentials
    are the degree-16 Taylor polynomial with scaling and squaring
    (:func:`~stability.expm.expm_soa`, no linear solves).  ``optional_first``: the first
    (coarsest) count is dropped from the result, not an error, when it does not resolve ``P``.
    """
    q = len(scheme.nodes)
    n = wrapped.n
    times = _gauss_times(scheme.nodes, period, tuple(Ns))
    Ntot = sum(Ns)
    balanced = isinstance(wrapped, _Balanced)  # then the balancing is applied with the transposition
    raw = (wrapped.wrapped if balanced else wrapped).evaluate(times).reshape(Ntot, q, n, n)
    ratio = wrapped.ratio if balanced else None
    h = _step_lengths(period, tuple(Ns))
    if scheme.order == 6 and not keep_factors:
        compiled = _compiled_levels(raw, ratio, h, Ns, strict, optional_first, scheme)
        if compiled is not None:
            return compiled
    Pg = np.empty((q, n, n, Ntot))  # matrix-major (q, n, n, Ntot)
    if balanced:
        np.multiply(raw.transpose(1, 2, 3, 0), ratio[None, :, :, None], out=Pg)
    else:
        Pg[...] = raw.transpose(1, 2, 3, 0)
    with np.errstate(over="ignore", invalid="ignore"):
        Om, C = magnus_exponents_soa(scheme, Pg, h, split=True)
        if strict and scheme.order > 2:
            column = np.abs(C).sum(axis=0).max(axis=0)  # per sub-interval
            levels = np.maximum.reduceat(column, [0, *itertools.accumulate(Ns[:-1])])
            if _first_resolved_level(scheme, levels, Ns, optional_first):
                keep = slice(Ns[0], Ntot)  # the coarsest level dropped
                Om, h = Om[:, :, keep], h[keep]
                Ns = Ns[1:]
        E = expm_soa(Om)
        products = _level_products(E, Ns)
        # the diagonals as a strided view of the (n n, N) rows
        traces = np.add.reduceat(Om.reshape(n * n, -1)[:: n + 1].sum(axis=0), [0, *itertools.accumulate(Ns[:-1])])
        out = []
        start = 0
        for i, N in enumerate(Ns):
            block = slice(start, start + N)
            start += N
            # a non-finite factor makes the product non-finite
            Phi = products[i]
            if not np.isfinite(Phi).all():
                raise _overflowed(scheme, N, float(np.abs(Om[:, :, block]).sum(axis=0).max()))
            factors = np.ascontiguousarray(E[:, :, block].transpose(2, 0, 1)) if keep_factors else None
            out.append(_Solve(N, Phi, _spectrum(Phi), float(traces[i]), factors))
    return out


def _first_resolved_level(scheme: MagnusScheme, level_corr: np.ndarray, Ns: Sequence[int],
                          optional_first: bool) -> int:
    """The commutator test of a batch of levels: ``level_corr[i]`` is the largest commutator part
    ``||Omega_k - h Pbar_k||_1`` of level ``i``.  Returns 1 when the coarsest level does not resolve
    ``P`` and may be dropped (``optional_first``; the caller refines further), else 0; raises
    :class:`_Unresolved` when a kept level does not resolve it (a NaN does not)."""
    corrs = level_corr.tolist()  # a handful of numbers
    first = int(optional_first and len(Ns) > 1 and not corrs[0] <= COMMUTATOR_LIMIT)
    if not all(c <= COMMUTATOR_LIMIT for c in corrs[first:]):  # (a NaN is not resolved)
        corr = float(np.max(level_corr[first:]))
        raise _Unresolved(
            f"{scheme.name}: the commutator terms of the Magnus exponent reach {corr:.3g} "
            f"with {'/'.join(str(N) for N in Ns[first:])} sub-intervals (limit {COMMUTATOR_LIMIT:g}): "
            f"the steps do not resolve P"
        )
    return first


def _overflowed(scheme: MagnusScheme, N: int, size: float) -> _Unresolved:
    return _Unresolved(
        f"{scheme.name}: the monodromy matrix overflowed with {N} sub-intervals (solutions "
        f"grow beyond 1e308 within one period, h*||P|| up to {size:.3g})",
        genuine_overflow=True,
    )


def _compiled_levels(P: np.ndarray, ratio: Optional[np.ndarray], h: Any, Ns: list[int], strict: bool,
                     optional_first: bool, scheme: MagnusScheme) -> Optional[list[_Solve]]:
    """:func:`_magnus_solves_small`'s Magnus-6 batch by the compiled kernel
    (:mod:`stability._compiled`; ``P`` ``(sum Ns, 3, n, n)`` unbalanced, ``ratio`` the balancing),
    with the same checks; None where that kernel is not available."""
    from stability import _compiled

    if len(Ns) == 1:
        h = np.full(Ns[0], h)
    done = _compiled.magnus6_levels(P, h, Ns, ratio)
    if done is None:
        return None
    phis, stats = done
    first = _first_resolved_level(scheme, stats[:, 1], Ns, optional_first) if strict else 0
    finite = bool(np.isfinite(phis[first:]).all())
    out = []
    for i in range(first, len(Ns)):
        Phi = phis[i]
        if not finite and not np.isfinite(Phi).all():
            raise _overflowed(scheme, Ns[i], float(stats[i, 2]))
        out.append(_Solve(Ns[i], Phi, _spectrum(Phi), float(stats[i, 0]), None))
    return out


def _level_products(E: np.ndarray, Ns: Sequence[int]) -> list[np.ndarray]:
    """``E_N ... E_1`` of each consecutive block of ``Ns`` factors of the stack ``E`` ``(n, n, sum Ns)``.

    When the counts double from level to level (``Ns[i] = 2^i Ns[0]``, the refinement ladder), the
    finest block is reduced by one pairwise level, reduced together with the next one, and so on,
    until all have ``Ns[0]`` factors; then they reduce together (``log2 Ns[0]`` batched products
    for all the levels instead of one sequence each).  The same products in the same order as
    :func:`~stability.magnus.ordered_product_soa` on each block.
    """
    n = E.shape[0]
    bounds = [0, *itertools.accumulate(Ns)]  # (np.cumsum of a short list costs more)
    N0 = Ns[0]
    ladder = len(Ns) > 1 and all(N == N0 * 2**i for i, N in enumerate(Ns))
    if not ladder:
        return [ordered_product_soa(E[:, :, bounds[i]:bounds[i + 1]]) for i in range(len(Ns))]
    # contiguous (sum Ns, n, n): batched matmul on the strided halves costs less than einsum
    # on strided matrix-major views
    F = np.ascontiguousarray(E.transpose(2, 0, 1))
    blocks = [F[bounds[i]:bounds[i + 1]] for i in range(len(Ns))]
    # from the finest down: carry = the blocks already reduced to the current count, interleaved
    carry = blocks[-1].reshape(-1, 1, n, n)  # (k, width, n, n)
    for i in range(len(Ns) - 2, -1, -1):
        half = np.matmul(carry[1::2], carry[0::2])
        # prepend level i (same count now) as the first interleaved sequence
        carry = np.concatenate([blocks[i][:, None], half], axis=1)
    products = ordered_product_interleaved(carry)  # (width, n, n): level order
    return list(products)


def _matrix_change(fine: np.ndarray, coarse: np.ndarray) -> float:
    """Normwise relative change of the (balanced) monodromy matrix between two solves."""
    with np.errstate(over="ignore", invalid="ignore"):
        scale_ = float(np.max(np.abs(fine))) or 1.0  # keep the norms in range
        value = float(np.linalg.norm((fine - coarse) / scale_) / np.linalg.norm(fine / scale_))
    return value if math.isfinite(value) else math.inf


class _Piece:
    """``P`` on one smooth piece ``[start, start + length]`` of the period, as a periodic matrix of
    period ``length`` (the Magnus solvers then place equal steps on the piece only)."""

    def __init__(self, target: Any, start: float, length: float) -> None:
        self.target = target
        self.start = start
        self.period = length
        self.n = target.n

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        return self.target.evaluate(self.start + np.asarray(times, dtype=float))

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([t]))[0]


def _piece_steps(N: int, pieces: Sequence[tuple[float, float]], period: float) -> list[int]:
    """Sub-intervals per smooth piece for about ``N`` in all: proportional to the piece lengths."""
    return [max(1, int(round(N * length / period))) for _, length in pieces]


def _pieces(breakpoints: Sequence[float], period: float) -> tuple[tuple[float, float], ...]:
    """``(start, length)`` of the smooth pieces between sorted breakpoints in ``(0, T)``."""
    edges = [0.0, *breakpoints, period]
    return tuple((a, b - a) for a, b in zip(edges[:-1], edges[1:]))


def _magnus_method(scheme: MagnusScheme) -> Callable[..., _Propagation]:
    def run(
        wrapped: PeriodicMatrixFunction,
        period: float,
        *,
        n_steps: Optional[int],
        rtol: float,
        error_estimate: bool,
        max_steps: int,
        reference: Optional[ReferenceOptions] = None,
        accuracy: str = "moduli",
        keep_factors: bool = False,
        probe: Optional[np.ndarray] = None,
        breakpoints: Sequence[float] = (),
    ) -> _Propagation:
        q = len(scheme.nodes)
        p = scheme.order
        evaluations = 0
        pieces = _pieces(breakpoints, period) if breakpoints else ()

        def piecewise(N: int, strict: bool) -> _Solve:
            """The product of the piece propagators, steps landing on every breakpoint."""
            nonlocal evaluations
            counts = _piece_steps(N, pieces, period)
            evaluations += q * sum(counts)
            Phi = np.eye(wrapped.n)
            log_det = 0.0
            factors = []
            for (start, length), Ni in zip(pieces, counts):
                part = _magnus_solve(scheme, _Piece(wrapped, start, length), length, Ni, keep_factors, strict)
                Phi = part.monodromy @ Phi
                log_det += part.log_abs_det
                if keep_factors:
                    factors.append(part.factors)
            _check_monodromy(Phi, scheme)
            return _Solve(sum(counts), Phi, _spectrum(Phi), log_det,
                          np.concatenate(factors) if keep_factors else None)

        def solve(N: int, strict: bool = True, third: int = 0) -> _Solve:
            nonlocal evaluations
            if pieces:
                return piecewise(N, strict)
            evaluations += q * N
            return _magnus_solve(scheme, wrapped, period, N, keep_factors, strict, third)

        def solve_many(Ns: list[int], strict: bool = True, optional_first: bool = False) -> list[_Solve]:
            """Solves with each of ``Ns`` sub-intervals (one batch for small systems); with
            ``optional_first`` the first one is left out where it does not resolve ``P``."""
            nonlocal evaluations
            if wrapped.n > SMALL_N or pieces:
                out = []
                for i, N in enumerate(Ns):
                    try:
                        out.append(solve(N, strict))
                    except _Unresolved:
                        if not (optional_first and i == 0):
                            raise
                return out
            _memory_check(scheme, sum(Ns), wrapped.n)
            evaluations += q * sum(Ns)
            return _magnus_solves_small(scheme, wrapped, period, list(Ns), keep_factors, strict, optional_first)

        fixed = None
        if n_steps is not None:
            try:
                fine = solve(n_steps, strict=False, third=COMPANION_LEVELS if error_estimate else 0)
            except _Unresolved as exc:
                raise FloquetError(f"{exc}; use more steps (n_steps) or method='magnus2'") from None
            levels = [fine]
            if error_estimate and fine.third is not None:
                # N / 3 and N / 9 came with the fine one (magnus2, large n): ratio 3
                link, chain = fine.third, []
                while link is not None:
                    chain.append(link)
                    link = link.third
                levels = chain[::-1] + [fine]
            elif error_estimate and n_steps >= 2:
                coarser = [n_steps // 4] if n_steps % 4 == 0 and n_steps >= 8 else []
                try:
                    levels = solve_many(coarser + [n_steps // 2], strict=False) + [fine]
                except _Unresolved:
                    levels = [fine]
                    fixed = math.inf  # the coarser solves are meaningless: no certificate
            info = _level_estimates(levels, p, accuracy) if len(levels) >= 2 else None
            at_cap = False
        else:
            fine, levels, info, at_cap = _adaptive(
                solve, solve_many, lambda lv: _level_estimates(lv, p, accuracy), rtol, max_steps, scheme,
                lambda: _start_steps(scheme, wrapped, period, max_steps, probe), accuracy)
        if info is not None:
            changes, est, phase_est = info.estimates, info.error, info.phase_error
        else:
            changes, est, phase_est = None, (math.nan if fixed is None else fixed), math.nan
        companions = []
        link = fine.third if n_steps is not None else None
        while link is not None:
            companions.append((link.n_steps, link.monodromy))
            link = link.third
        return _Propagation(fine.monodromy, fine.spectrum, fine.log_abs_det, fine.n_steps, evaluations,
                            est, changes, fine.factors, phase_est, tuple(companions),
                            observed_order=math.nan if info is None else info.observed_order,
                            order_checked=info is not None and info.order_checked,
                            clusters=() if info is None else info.clusters,
                            at_cap=at_cap, scheme_order=p,
                            noise_levels=None if info is None else info.noise)

    run.__name__ = f"_run_{scheme.name}"
    return run


def _first_resolved(solve, N: int, max_steps: int, scheme: MagnusScheme) -> _Solve:
    """The first solve at ``N, 2N, 4N, ...`` whose sub-intervals resolve ``P``."""
    last: Optional[_Unresolved] = None
    reason = f"{N} steps exceed the limit of {max_steps} (max_steps)"
    while N <= max_steps:
        try:
            return solve(N)
        except _Unresolved as exc:
            if "GB of work arrays" in str(exc):
                reason = f"{last}; refining further {exc}" if last is not None else str(exc)
                break
            last = exc
            reason = f"{exc}; no step count up to {max_steps} resolves it"
            N *= 2
    hint = " (the commutator terms of high-order Magnus schemes grow with h||P||: use method='magnus2' " \
           "for stiff, fast systems)" if scheme.order > 2 else ""
    if last is not None and last.genuine_overflow:
        hint = " (solutions grow beyond double precision within one period)"
    raise FloquetError(reason + hint)


def _start_steps(scheme: MagnusScheme, wrapped: PeriodicMatrixFunction, period: float, max_steps: int,
                 probe: Optional[np.ndarray] = None) -> int:
    """First sub-interval count: where the commutator part of the exponents is about :data:`START_COMMUTATOR`.

    Measured at ``INITIAL_STEPS`` on :data:`PROBE_INTERVALS` sub-intervals of
    length ``T / INITIAL_STEPS`` spread over the period and scaled with
    ``N^-(p-1)`` (the commutator terms of a ``p``-th order scheme are
    ``O(h^(p-1))`` relative to ``h ||P||`` once the steps resolve ``P``); a
    power of two times ``INITIAL_STEPS``.  ``probe`` is ``P`` (balanced) at the
    Gauss nodes of those sub-intervals, shape ``(PROBE_INTERVALS, q, n, n)``,
    when the caller already has it (:func:`_probe_and_samples`: one evaluation
    serves balancing, the period check and this probe).
    """
    N = INITIAL_STEPS
    if scheme.order <= 2:
        return N
    h = period / N
    if probe is None:
        probe, _ = _probe_and_samples(wrapped, period, scheme)
    corr = _commutator_size(scheme, probe, h)
    if not math.isfinite(corr):
        return N
    while corr > START_COMMUTATOR and 2 * N <= max_steps:
        N *= 2
        corr /= 2.0 ** (scheme.order - 1)
    return N


def _commutator_size(scheme: MagnusScheme, Pg: np.ndarray, h: float) -> float:
    """``max_k ||Omega_k - h Pbar_k||_1`` over the sub-intervals of ``Pg`` (shape ``(m, q, n, n)``)."""
    if scheme.order == 6 and Pg.shape[-1] <= SMALL_N:
        from stability import _compiled

        done = _compiled.magnus6_levels(Pg, np.full(Pg.shape[0], h), [Pg.shape[0]])
        if done is not None:
            return float(done[1][0, 1])
    with np.errstate(over="ignore", invalid="ignore"):
        _, C = magnus_exponents(scheme, Pg, h, split=True)
        return float(np.max(np.sum(np.abs(C), axis=1)))


def _probe_and_samples(wrapped: PeriodicMatrixFunction, period: float,
                       scheme: Optional[MagnusScheme]) -> tuple[Optional[np.ndarray], np.ndarray]:
    """``P`` for the start-step probe and the balancing samples, from one evaluation.

    The probe sub-intervals are every other one of ``INITIAL_STEPS`` equal
    ones (``PROBE_INTERVALS`` of them, of length ``h = T / INITIAL_STEPS``,
    starting at ``t_j = 2 j h``); the :data:`BALANCE_SAMPLES` balancing samples
    are their midpoints ``t_j + h / 2``, equally spaced over the period (the
    Magnus-6 middle Gauss node is one of them).  Returns
    ``(probe (PROBE_INTERVALS, q, n, n) or None, samples (BALANCE_SAMPLES, n, n))``, unbalanced.
    """
    probed = scheme is not None and scheme.order > 2  # (the start rule of lower orders needs no probe)
    times, picks, middle = _probe_grid(period, tuple(scheme.nodes) if probed else (0.0, 0.5))
    P = wrapped.evaluate(times)
    P = P.reshape(BALANCE_SAMPLES, -1, *P.shape[1:])
    if not probed:
        # the starts k T / 8 are evaluated too (and discarded) so that P's own input checks (a mass
        # matrix that vanishes at T/2, a NaN at t = 0) see the equispaced grid k T / 8 as well
        return None, P[:, middle]
    return P[:, picks], P[:, middle]


@functools.lru_cache(maxsize=64)
def _probe_grid(period: float, nodes: tuple) -> tuple[np.ndarray, Any, int]:
    """:func:`_probe_and_samples`' times (read-only; cached like :func:`_gauss_times`): the probe
    sub-intervals' starts, ``nodes`` and midpoints in time order, interval by interval; with where
    ``nodes`` (a slice when they are consecutive) and the midpoint are in each interval's row."""
    h = period / INITIAL_STEPS
    starts = np.arange(0, INITIAL_STEPS, INITIAL_STEPS // BALANCE_SAMPLES) * h
    grid = sorted(set(nodes) | {0.0, 0.5})
    times = (starts[:, None] + h * np.array(grid)[None, :]).ravel()
    times.flags.writeable = False
    index = [grid.index(c) for c in nodes]
    picks = slice(index[0], index[-1] + 1) if index == list(range(index[0], index[-1] + 1)) else index
    return times, picks, grid.index(0.5)


def _adaptive(solve, solve_many, estimate, rtol: float, max_steps: int, scheme: MagnusScheme,
              start_steps: Callable[[], int], accuracy: str = "moduli"):
    """Refinement until the estimate of three levels (:func:`_level_estimates`) is ``<= rtol``.

    1. Pilot: the first resolved count ``N`` (:func:`_start_steps`), solved with ``N / 2``, ``N``
       and ``2 N`` sub-intervals (one batch for small systems): three levels, so that the order of
       convergence is observed before any estimate is trusted.
    2. While the estimate ``e`` of the finest level exceeds ``rtol``: the next count is
       ``N (e / (SAFETY rtol))^(1/q)`` with ``q`` the order used by the estimate (at least 1.25
       and at most :data:`MAX_REFINE_RATIO` times ``N``), appended as a new level.
    3. Accepted when ``e <= rtol`` over three levels; at ``max_steps``, or when the remaining
       excess is the bound of a defective group whose matrix estimate is at the rounding level
       (no step count improves it), returned with ``at_cap = True`` (the caller reports it).

    Returns ``(finest solve, levels, estimate, at_cap)``.
    """
    p = scheme.order
    N0 = start_steps()
    levels: list = []
    if 2 * N0 <= max_steps:
        Ns = ([N0 // 2] if N0 >= 4 else []) + [N0, 2 * N0]
        try:
            levels = list(solve_many(Ns, optional_first=N0 >= 4))
        except _Unresolved:
            levels = []
    if not levels:
        levels = [_first_resolved(solve, N0, max_steps, scheme)]
    while True:
        info = estimate(levels) if len(levels) >= 2 else None
        fine = levels[-1]
        est = math.inf
        if info is not None:
            est = info.error
            if accuracy == "multipliers":
                est = max(est, info.phase_error)
            if info.order_checked and est <= rtol:
                return fine, levels, info, False
            if info.order_checked and info.rounding_limited and info.clusters:
                return fine, levels, info, True
            keep = fine.spectrum.log_moduli >= fine.spectrum.log_moduli[0] + math.log(ESTIMATE_FLOOR)
            excess = keep & (info.estimates > rtol)
            if info.order_checked and np.all(info.estimates[excess] <= ROUNDING_STOP * info.noise[excess]):
                return fine, levels, info, True  # what is left is rounding: more steps add to it
        if fine.n_steps >= max_steps:
            return fine, levels, info, True
        if info is not None and info.order_checked and math.isfinite(est) and est > 0:
            order = info.observed_order if math.isfinite(info.observed_order) else p
            order = min(max(order, 1.0), p)
            wanted = (est / (SAFETY * rtol)) ** (1.0 / order)
            grow = min(max(wanted, 1.25), MAX_REFINE_RATIO)
            if order < LOW_ORDER_FRACTION * p and fine.n_steps * wanted > max_steps:
                # at a low observed order rtol is out of reach: straight to the best the limit gives
                grow = max_steps / fine.n_steps
        else:
            grow = 2.0  # not enough levels yet: classical doubling
        N_next = min(int(math.ceil(fine.n_steps * grow)), max_steps)
        if N_next <= fine.n_steps:
            return fine, levels, info, True
        try:
            levels.append(solve(N_next))
        except _Unresolved:
            levels = [_first_resolved(solve, 2 * N_next, max_steps, scheme)]


def _paper_method(
    wrapped: PeriodicMatrixFunction,
    period: float,
    *,
    n_steps: Optional[int],
    rtol: float,
    error_estimate: bool,
    max_steps: int,
    reference: Optional[ReferenceOptions] = None,
    accuracy: str = "moduli",
    keep_factors: bool = False,
    probe: Optional[np.ndarray] = None,
    breakpoints: Sequence[float] = (),
) -> _Propagation:
    opts = reference or ReferenceOptions()
    Phi, nfev = paper_monodromy(wrapped, period, opts)
    spec = _spectrum(Phi)
    est = math.nan
    changes = None
    evaluations = nfev
    if error_estimate:
        # the difference to a 100x looser tolerance bounds the error of this one
        loose = ReferenceOptions(opts.integrator, rtol=opts.rtol * 100, atol=opts.atol * 100)
        Phi2, nfev2 = paper_monodromy(wrapped, period, loose)
        evaluations += nfev2
        spec2 = _spectrum(Phi2)
        changes = _select_changes(spec, spec2, accuracy)
        est = _estimate(changes, spec, 1.0, accuracy)
        phase_est = _estimate(_phase_changes(spec, spec2), spec, 1.0)
    else:
        phase_est = math.nan
    return _Propagation(Phi, spec, _log_abs_det(Phi[None]), nfev, evaluations, est, changes,
                        phase_error_estimate=phase_est)


_SCHEMES = {"magnus6": MAGNUS6, "magnus4": MAGNUS4, "magnus2": MAGNUS2}

#: Registry of Floquet methods (name -> implementation).
METHODS: dict[str, Callable[..., _Propagation]] = {
    "magnus6": _magnus_method(MAGNUS6),
    "magnus4": _magnus_method(MAGNUS4),
    "magnus2": _magnus_method(MAGNUS2),
    "paper": _paper_method,
}


# --------------------------------------------------------------------------- driver
#: Sample times (fractions of the period) at which |P| is averaged for balancing.
BALANCE_SAMPLES = 8


class _Balanced:
    """``D^-1 P(t) D`` with ``D = diag(scale)``: same multipliers, better scaling."""

    def __init__(self, wrapped: PeriodicMatrixFunction, scale: np.ndarray) -> None:
        self.wrapped = wrapped
        self.period = wrapped.period
        self.n = wrapped.n
        self.ratio = scale[None, :] / scale[:, None]  # powers of two: the scaling is exact

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        return self.wrapped.evaluate(times) * self.ratio

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([t]))[0]


def _samples(wrapped: PeriodicMatrixFunction, period: float) -> np.ndarray:
    """``P`` at :data:`BALANCE_SAMPLES` equally spaced times (balancing and the scale check)."""
    return wrapped.evaluate(np.arange(BALANCE_SAMPLES) * (period / BALANCE_SAMPLES))


def _balancing_scale(samples: np.ndarray) -> Optional[np.ndarray]:
    """Diagonal scaling from LAPACK's balancing (``dgebal``) of ``mean |P(t)|``; ``None`` if not worth it."""
    if samples.shape[-1] < 2:
        return None
    A = np.abs(samples).sum(axis=0)  # the balancing of mean |P| (invariant under the factor 1/m)
    if np.count_nonzero(A) == np.count_nonzero(np.diagonal(A)):
        return None  # diagonal (or zero): nothing to balance
    *_, scale, info = dgebal(A, scale=1, permute=0)
    factors = scale.tolist()  # n numbers: plain Python is cheaper than two numpy reductions
    if info != 0 or not all(map(math.isfinite, factors)) or all(f == 1.0 for f in factors):
        return None
    return np.asarray(scale, dtype=float)


def _check_period_scale(samples: np.ndarray, period: float, ratio: Optional[np.ndarray]) -> float:
    """Reject periods too long for double precision (see :data:`PERIOD_SCALE_LIMIT`); return ``T max||P||``.

    ``||P||`` is the 1-norm of the balanced samples (``D^-1 P D``, ``ratio`` the balancing's
    ``d_j / d_i`` as :class:`_Balanced` holds it, None without balancing), within a small
    factor of the spectral radius for the balanced matrices met here.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        balanced = samples if ratio is None else samples * ratio
        scale_ = period * float(np.abs(balanced).sum(axis=1).max())
    if not scale_ <= PERIOD_SCALE_LIMIT:
        raise ValueError(
            f"the period T = {period:.3g} s is too long for the time scales of P(t) "
            f"(T * ||P|| = {scale_:.3g} > {PERIOD_SCALE_LIMIT:.0e}): multipliers like "
            f"exp(T lambda) and their phases are beyond double precision -- is the frequency "
            f"(omega = 2 pi / T = {2 * math.pi / period:.3g} rad/s) too small?"
        )
    return scale_


#: QR sweeps over one period for ``small_multipliers="qr"`` (each sweep is one period
#: of power iteration; moduli 1e-17 apart converge in one sweep).
QR_SWEEPS = 4


def _qr_log_moduli(factors: np.ndarray, sweeps: int = QR_SWEEPS) -> tuple[np.ndarray, np.ndarray]:
    """ln|rho_i| by QR sweeps over the propagators; also the change over the last sweep."""
    n = factors.shape[-1]
    Q = np.eye(n)
    prev = None
    logs = np.zeros(n)
    for _ in range(sweeps):
        logs = np.zeros(n)
        for E in factors:
            Q, R = np.linalg.qr(E @ Q)
            d = np.abs(np.diag(R))
            with np.errstate(divide="ignore"):
                logs += np.log(d)
        if prev is not None:
            change = np.abs(logs - prev)
        prev = logs
    # pairs of equal modulus (complex multipliers) do not triangularise; their sum is exact
    i = 0
    out = logs.copy()
    while i < n - 1:
        if change[i] > 1e-6 * max(1.0, abs(logs[i])) and change[i + 1] > 1e-6 * max(1.0, abs(logs[i + 1])):
            out[i] = out[i + 1] = 0.5 * (logs[i] + logs[i + 1])
            change[i] = change[i + 1] = abs((logs[i] + logs[i + 1]) - (prev[i] + prev[i + 1]))
            i += 2
        else:
            i += 1
    return out, change


def _qr_small_multipliers(spec: _Spectrum, digits: np.ndarray, factors: np.ndarray, noise: float):
    """Replace the moduli below the noise floor by their QR-sweep values."""
    logs, change = _qr_log_moduli(factors)
    order = np.argsort(-logs)
    logs, change = logs[order], change[order]
    small = np.exp(spec.log_moduli) <= 100.0 * noise
    new_logs = spec.log_moduli.copy()
    new_logs[small] = logs[small]
    with np.errstate(divide="ignore"):
        qr_digits = np.clip(-np.log10(np.maximum(change / np.maximum(np.abs(logs), 1e-300), 1e-16)), 0.0, 16.0)
    new_digits = digits.copy()
    new_digits[small] = qr_digits[small]
    phases = np.angle(spec.values)
    with np.errstate(under="ignore"):
        values = np.exp(new_logs) * np.exp(1j * phases)
    return _Spectrum(values, new_logs), new_digits


def _liouville(log_det: float, trace: float) -> float:
    """``|det / exp(trace) - 1|`` from logarithms (inf when it overflows)."""
    d = log_det - trace
    if not math.isfinite(d) or d > 700.0:
        return math.inf
    return abs(math.expm1(d))


def floquet(
    P: Any,
    period: Optional[float] = None,
    *,
    method: str = DEFAULT_METHOD,
    n_steps: Optional[int] = None,
    rtol: float = DEFAULT_RTOL,
    stability_tol: float = 1e-8,
    error_estimate: bool = True,
    max_steps: int = MAX_STEPS,
    reference: Optional[ReferenceOptions] = None,
    balance: bool = True,
    accuracy: str = "moduli",
    small_multipliers: str = "flag",
    expm_blocks: Optional[Sequence[int]] = None,
    breakpoints: Optional[Sequence[float]] = None,
) -> FloquetResult:
    """Floquet multipliers and stability verdict of ``x' = P(t) x``.

    Parameters
    ----------
    P : callable or periodic-system object
        ``t -> (n, n)`` array, T-periodic.  An object with ``.period`` (e.g.
        :class:`~stability.periodic.SecondOrderPeriodicSystem` or
        :class:`~mbs_models.reduced.ReducedModel`) carries its own period;
        one with ``evaluate(times) -> (m, n, n)`` is evaluated vectorised;
        one with ``trace_integral()`` supplies ``int tr P`` in closed form.
    period : float, optional
        ``T > 0``; required when ``P`` has no ``.period``.
    method : str
        A key of :data:`METHODS` (``"magnus6"``, ``"magnus4"``, ``"paper"``).
    n_steps : int, optional
        Fixed number of sub-intervals for the Magnus methods.  Default:
        adaptive refinement (see the module notes) until the Richardson
        estimate is ``<= rtol``.
    rtol : float
        Target relative accuracy (adaptive mode) of what ``accuracy`` names;
        the default :data:`DEFAULT_RTOL` (2e-9) is five times below the 1e-8 the package
        promises for the spectral radius and 500 times below :data:`CONTRACT_RTOL`.
    stability_tol : float
        Half-width of the band around ``|rho| = 1`` called critical.
    error_estimate : bool
        With a fixed ``n_steps``, also solve with ``n_steps // 2`` to report
        a Richardson estimate (the adaptive mode always has one).
    max_steps : int
        Upper limit on sub-intervals in the adaptive mode.
    reference : ReferenceOptions, optional
        Integrator and tolerances of the ``"paper"`` method (default Radau,
        ``rtol=1e-11``); ignored by the other methods.
    accuracy : {"moduli", "multipliers", "dominant"}
        What the refinement certifies to ``rtol``: the moduli (default: the
        stability verdict depends on nothing else), or the multipliers, i.e.
        moduli and phases.  A phase is ``T`` times an oscillation frequency
        modulo ``2 pi``, so at ``Omega = 2 pi`` (107 elastic oscillations per
        period) its absolute error is ~700 times the frequency's relative
        error and needs 3-4 times the sub-intervals of the moduli.  The phase
        error estimate is reported either way (``phase_error_estimate``).
        ``"dominant"``: the estimate (and the refinement) covers only the
        spectral radius and the multipliers that could be it
        (:func:`dominant_mask`: moduli within ``DOMINANT_BAND`` of it, or whose
        error interval widened ``DOMINANT_SAFETY`` times reaches its one),
        so inaccurate moduli well inside do not force refinement.
    small_multipliers : {"flag", "qr"}
        Multipliers below the noise floor of the formed product are
        ``"flag"``-ged with ``reliable_digits = 0`` (default, free), or their
        moduli are computed accurately by ``"qr"``: repeated QR sweeps over
        the sub-interval propagators (the discrete QR method for Lyapunov
        exponents, applied to the periodic product: each sweep is one more
        period, so the triangular factors converge to the periodic Schur form
        at the rate of the ratio of consecutive moduli).  ``log_moduli`` then
        holds e.g. -3172.8 for a multiplier of 1e-1378.  Costs a few
        milliseconds more (a Python loop over the sub-intervals); factor
        methods only.
    balance : bool
        Work with ``D^-1 P(t) D`` for a constant diagonal ``D`` (powers of 2,
        LAPACK's balancing of the mean ``|P|``): the multipliers are
        unchanged, but badly scaled models (the Exudyn linearisation mixes
        metres and radians; its 1-norm is 1e4 times its spectral radius) get
        matrix exponentials that are cheaper and far more accurate.  The
        returned monodromy matrix is transformed back.
    expm_blocks : sequence of int, optional
        Sizes of the contiguous diagonal blocks over which ``P`` is nearly block
        diagonal (1 or 2; a frozen-modal frame's clusters, passed by
        :func:`stability.modal.modal_floquet`).  The factors of systems of at least
        :data:`BLOCK_EXPM_MIN_N` states are then exponentiated by block diagonalisation
        (:func:`stability.expm.expm_near_block_diagonal`: 3 GEMMs and one LU solve
        instead of ~21 GEMMs, equal to ``scipy.linalg.expm`` within its error bound),
        each factor falling back to ``scipy.linalg.expm`` where that method refuses;
        the number of fallbacks is logged (INFO).  Default: ``scipy.linalg.expm``.
    breakpoints : sequence of float, optional
        Times in ``[0, T)`` where ``P(t)`` or one of its derivatives jumps (switching times,
        the corners of a trapezoidal velocity profile, a cam law's acceleration jumps).  The
        sub-intervals then land on them: each smooth piece gets equal steps in proportion to its
        length, and the whole converges at the method's order again (equal steps across a jump
        converge like ``1/N``).  Default: ``P.breakpoints`` when ``P`` has that attribute
        (e.g. :class:`~stability.periodic.SecondOrderPeriodicSystem`), else none.  Without
        them a non-smooth ``P`` is detected by its low observed order
        (:attr:`FloquetResult.observed_order`, with a warning), and the estimate uses that order.
        Factor methods only (``"paper"`` integrates adaptively and ignores them).

    Returns
    -------
    FloquetResult

    Raises
    ------
    ValueError
        On a non-positive or non-finite period, a ``P`` that returns a
        non-square, wrongly shaped, NaN or inf matrix, an unknown method or
        invalid options.

    Notes
    -----
    Maths: the monodromy matrix ``Phi(T)`` solves ``Phi' = P Phi``,
    ``Phi(0) = I``; its eigenvalues are the Floquet multipliers, and the
    origin is asymptotically stable iff all ``|rho_i| < 1`` (paper, Sec. 2).
    Liouville's formula ``det Phi(T) = exp(int_0^T tr P dt)`` is checked on
    the returned multipliers (a necessary condition; the step-doubling
    estimate certifies the accuracy).

    References
    ----------
    .. [1] Floquet, G., Ann. Sci. ENS 12 (1883) 47-88.
    .. [2] Blanes, S., Casas, F., Oteo, J. A., Ros, J., Physics Reports 470
           (2009) 151-238.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.array([[0.0, 1.0], [-4.0, -0.2]])
    >>> res = floquet(lambda t: A, period=1.0)
    >>> bool(np.allclose(res.monodromy, __import__("scipy").linalg.expm(A)))
    True
    """
    t0 = time.perf_counter()
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(sorted(METHODS))}")
    if n_steps is not None and (int(n_steps) != n_steps or n_steps < 1):
        raise ValueError(f"n_steps must be a positive integer, got {n_steps!r}")
    if not (math.isfinite(rtol) and rtol > 0):
        raise ValueError(f"rtol must be finite and > 0, got {rtol!r}")
    if small_multipliers not in ("flag", "qr"):
        raise ValueError(f"small_multipliers must be 'flag' or 'qr', got {small_multipliers!r}")
    if small_multipliers == "qr" and method == "paper":
        raise ValueError("small_multipliers='qr' needs a factor method (magnus2/4/6), not 'paper'")
    if accuracy not in ACCURACIES:
        raise ValueError(f"accuracy must be one of {', '.join(map(repr, ACCURACIES))}, got {accuracy!r}")
    if not (math.isfinite(stability_tol) and stability_tol >= 0):
        raise ValueError(f"stability_tol must be finite and >= 0, got {stability_tol!r}")
    wrapped = PeriodicMatrixFunction(P, period)
    T = wrapped.period
    bp = _normalise_breakpoints(breakpoints if breakpoints is not None else getattr(P, "breakpoints", None), T)
    if expm_blocks is not None:
        expm_blocks = tuple(int(b) for b in expm_blocks)
        if not expm_blocks or min(expm_blocks) < 1 or sum(expm_blocks) != wrapped.n:
            raise ValueError(f"expm_blocks must be positive block sizes summing to n = {wrapped.n}, "
                             f"got {len(expm_blocks)} blocks summing to {sum(expm_blocks)}")
    scheme = _SCHEMES.get(method) if n_steps is None else None
    probe, samples = _probe_and_samples(wrapped, T, scheme)
    scale = _balancing_scale(samples) if balance else None
    target = wrapped if scale is None else _Balanced(wrapped, scale)
    ratio = None if scale is None else target.ratio
    time_scale = _check_period_scale(samples, T, ratio)
    if expm_blocks is not None:  # a diagonal scaling keeps the block structure
        target = _BlockExpmTarget(target, expm_blocks)
    if probe is not None and scale is not None:
        probe = probe * ratio
    # overflow, 0 * inf, log 0 and underflow are all detected and handled explicitly below
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        return _floquet_body(P, method, n_steps, rtol, stability_tol, error_estimate, max_steps, reference,
                             accuracy, small_multipliers, wrapped, T, scale, target, time_scale, t0, probe, bp)


def _normalise_breakpoints(breakpoints: Any, period: float) -> tuple:
    """Sorted distinct breakpoints in ``(0, T)`` (taken modulo ``T``; ``0`` is a step boundary anyway)."""
    if breakpoints is None:
        return ()
    try:
        values = np.asarray(breakpoints, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"breakpoints must be a sequence of times, got {breakpoints!r}") from None
    if not np.isfinite(values).all():
        raise ValueError(f"breakpoints must be finite times, got {breakpoints!r}")
    values = np.mod(values, period)
    tol = 1e-12 * period
    values = np.sort(values[(values > tol) & (values < period - tol)])
    out = []
    for v in values:
        if not out or v - out[-1] > tol:
            out.append(float(v))
    return tuple(out)


def _piecewise_trace(wrapped: Any, pieces: Sequence[tuple[float, float]]) -> float:
    """``int_0^T tr P dt`` by Gauss-Legendre on each smooth piece (32 and 64 nodes; the finer sum)."""
    total = 0.0
    for start, length in pieces:
        x, w = np.polynomial.legendre.leggauss(64)
        t = start + 0.5 * length * (x + 1.0)
        total += 0.5 * length * float(np.sum(w * np.trace(wrapped.evaluate(t), axis1=1, axis2=2)))
    return total


#: The reasons of :func:`_certify` and :func:`recertify` that do not depend on the multiplier.
_BELOW_FLOOR = "below the rounding floor of the formed product: phase (sign) unknown"
_OUTSIDE = f"modulus below {ESTIMATE_FLOOR:g} of the largest (outside the accuracy contract)"


def _certify(spec: _Spectrum, prop: _Propagation, rtol: float, accuracy: str, phase_known: np.ndarray,
             adaptive: bool, method: str) -> tuple[np.ndarray, tuple]:
    """Which multipliers meet the accuracy contract, and why each other one does not.

    Certified: modulus ``>= ESTIMATE_FLOOR`` of the largest (the contract's range), above the
    rounding floor, covered by what ``accuracy`` names, and estimated error ``<= rtol``.  Warns
    (``RuntimeWarning``) about a low observed order, defective / clustered groups whose bound is
    the ``m``-th root one, and covered multipliers that miss ``rtol``.
    """
    n = spec.values.size
    covered = (spec.log_moduli >= spec.log_moduli[0] + math.log(ESTIMATE_FLOOR)).tolist()
    phase_known = np.asarray(phase_known).tolist()  # (lists: the loops below index them per multiplier)
    reasons = [""] * n
    certified = [False] * n
    p = prop.scheme_order
    low = math.isfinite(p) and math.isfinite(prop.observed_order) and prop.observed_order < LOW_ORDER_FRACTION * p
    if low and adaptive:  # with a fixed n_steps the steps may simply be pre-asymptotic: reported, not warned
        warnings.warn(
            f"{method}: convergence order {prop.observed_order:.2g} observed, the method's is {p:g}: P(t) or "
            f"its derivatives are probably non-smooth inside the period; declare those times "
            f"(floquet(breakpoints=...), a system's or a drive's breakpoints) so that steps land on them",
            RuntimeWarning, stacklevel=4)
    group_of = {}
    for idx, bound, nu in prop.clusters:
        for i in idx:
            group_of[i] = (idx, bound, nu)
        lam = spec.values[list(idx)]
        rel = bound / float(np.min(np.abs(lam))) if np.min(np.abs(lam)) > 0 else math.inf
        relevant = any(covered[i] and phase_known[i] for i in idx)
        if relevant and nu > 1e-6 * float(np.max(np.abs(lam))) and rel > 1e-14:
            warnings.warn(
                f"{method}: multipliers {', '.join(str(i + 1) for i in idx)} (near {complex(lam.mean()):.6g}) are "
                f"defective or clustered (departure from normality {nu:.2g}): their error bound is the "
                f"{'square' if len(idx) == 2 else f'{len(idx)}-th'}-root (Henrici) bound {rel:.1e} relative",
                RuntimeWarning, stacklevel=4)
    changes = None if prop.changes is None else prop.changes.tolist()
    noise_levels = None if prop.noise_levels is None else prop.noise_levels.tolist()
    mask = covered
    if accuracy == "dominant" and changes is not None:
        mask = [c and d for c, d in zip(covered, dominant_mask(spec.log_moduli, prop.changes).tolist())]
    for i in range(n):
        if not phase_known[i]:
            reasons[i] = _BELOW_FLOOR + ("" if covered[i] else "; " + _OUTSIDE)
        elif not covered[i]:
            reasons[i] = _OUTSIDE
        elif changes is None and math.isinf(prop.error_estimate):
            reasons[i] = (f"no error estimate: the coarser solves of the estimate (n_steps / 2, / 4) do not "
                          f"resolve P with n_steps = {prop.n_steps}")
        elif changes is None:
            reasons[i] = "no error estimate (fixed n_steps with error_estimate=False)"
        elif not mask[i]:
            reasons[i] = "not covered by accuracy='dominant'"
        elif not changes[i] <= rtol:
            why = []
            if i in group_of:
                why.append(f"defective/clustered with multipliers "
                           f"{', '.join(str(j + 1) for j in group_of[i][0] if j != i)}")
            if low:
                why.append(f"observed order {prop.observed_order:.2g} (non-smooth P?)")
            rounding = noise_levels is not None and changes[i] <= ROUNDING_STOP * noise_levels[i]
            if rounding:
                why.append("the rounding level of the product of factors: more steps cannot lower it")
            elif prop.at_cap:
                why.append(f"refinement stopped at {prop.n_steps} steps")
            elif not adaptive:
                why.append(f"fixed n_steps = {prop.n_steps}")
            reasons[i] = f"error estimate {changes[i]:.1e} > rtol {rtol:.1e}" + (f" ({'; '.join(why)})" if why else "")
        else:
            certified[i] = True
    missed = [i for i in range(n) if covered[i] and mask[i] and phase_known[i] and changes is not None
              and not certified[i]]
    # a miss at the rounding level of a multiplier is logged, not warned about, while it is within the
    # accuracy the package promises for every covered multiplier (CONTRACT_RTOL)
    quiet = [i for i in missed if noise_levels is not None and changes[i] <= CONTRACT_RTOL
             and changes[i] <= ROUNDING_STOP * noise_levels[i]]
    if quiet:
        logger.info("%s: multipliers %s at their rounding level (estimates %s) miss rtol %.1e", method,
                    ", ".join(str(i + 1) for i in quiet), ", ".join(f"{changes[i]:.1e}" for i in quiet), rtol)
    missed = [i for i in missed if i not in quiet]
    if missed and adaptive:
        warnings.warn(
            f"{method}: error estimate {max(float(changes[i]) for i in missed):.2e} > rtol {rtol:.1e} "
            f"after {prop.n_steps} sub-intervals: multipliers {', '.join(str(i + 1) for i in missed)} are "
            f"not certified (FloquetResult.uncertified_reasons)",
            RuntimeWarning, stacklevel=4)
    return np.array(certified, dtype=bool), tuple(reasons)


def recertify(result: FloquetResult, rtol: Optional[float] = None) -> FloquetResult:
    """``result`` with :attr:`~FloquetResult.certified`, ``uncertified_reasons`` and ``phase_known``
    recomputed from its own per-multiplier estimates (``10^-reliable_digits``) against ``rtol``
    (default: ``result.rtol``, else :data:`CONTRACT_RTOL`).

    For results whose multipliers and estimates were replaced after the engine produced them
    (Richardson-extrapolated or checked frozen-modal solves, :mod:`stability.modal`).  A
    multiplier is certified when its modulus is ``>= ESTIMATE_FLOOR`` of the largest, above
    ``100 * noise_floor``, and its estimate is ``<= rtol``; a result without an estimate
    (``error_estimate`` NaN) certifies nothing.
    """
    from dataclasses import replace

    if rtol is None:
        rtol = result.rtol if math.isfinite(result.rtol) else CONTRACT_RTOL
    logs = np.asarray(result.log_moduli, float)
    n = logs.size
    covered = logs >= logs[0] + math.log(ESTIMATE_FLOOR)
    with np.errstate(under="ignore", over="ignore"):
        known = np.exp(logs) > 100.0 * result.noise_floor
        est = 10.0 ** -np.asarray(result.reliable_digits, float)
    has_estimate = math.isfinite(float(result.error_estimate))
    certified = covered & known & (est <= rtol) & has_estimate
    reasons = []
    for i in range(n):
        if certified[i]:
            reasons.append("")
        elif not known[i]:
            reasons.append(_BELOW_FLOOR + ("" if covered[i] else "; " + _OUTSIDE))
        elif not covered[i]:
            reasons.append(_OUTSIDE)
        elif not has_estimate:
            reasons.append("no error estimate")
        else:
            reasons.append(f"error estimate {est[i]:.1e} > rtol {rtol:.1e} (after {result.n_steps} steps)")
    return replace(result, rtol=float(rtol), certified=certified, uncertified_reasons=tuple(reasons),
                   phase_known=known)


def _floquet_body(P, method, n_steps, rtol, stability_tol, error_estimate, max_steps, reference, accuracy,
                  small_multipliers, wrapped, T, scale, target, time_scale, t0, probe=None,
                  breakpoints: tuple = ()) -> FloquetResult:
    """The evaluation part of :func:`floquet` (arguments validated, ``P`` wrapped and balanced)."""
    try:
        prop = METHODS[method](
            target,
            T,
            n_steps=None if n_steps is None else int(n_steps),
            rtol=rtol,
            error_estimate=error_estimate,
            max_steps=max_steps,
            reference=reference,
            accuracy=accuracy,
            keep_factors=small_multipliers == "qr",
            probe=probe,
            breakpoints=breakpoints,
        )
    except FloquetError as exc:
        finest = time_scale / (n_steps or max_steps)
        if finest > COMMUTATOR_LIMIT:
            raise FloquetError(
                f"{exc}; even {n_steps or max_steps} sub-intervals span h*||P|| = {finest:.3g} "
                f"each: the period T = {T:.3g} s is too long for the time scales of P (omega too small?)"
            ) from None
        raise
    if isinstance(target, _BlockExpmTarget) and target.exponentials:
        logger.log(logging.INFO if target.fallbacks else logging.DEBUG,
                   "floquet(%s): %d of %d factors fell back from block diagonalisation to scipy expm %s",
                   method, target.fallbacks, target.exponentials, target.reasons or "")
    spec = prop.spectrum
    rho = float(math.exp(spec.log_moduli[0]))
    if breakpoints and not callable(getattr(P, "trace_integral", None)):
        trace = _piecewise_trace(wrapped, _pieces(breakpoints, T))
    else:
        trace = _trace_integral(P, wrapped, T)
    n = spec.values.size
    noise = float(n * _EPS * _norm2(prop.monodromy))
    moduli = np.exp(spec.log_moduli)
    digits = np.log10(moduli / noise)  # the digits above the rounding floor ...
    if prop.changes is not None:  # ... and those the refinement estimate leaves
        digits = np.minimum(digits, -np.log10(np.maximum(prop.changes, 1e-16)))
    digits = np.minimum(np.maximum(digits, 0.0), 16.0)  # np.clip, cheaper
    # the phase (for a real multiplier: the sign) of a multiplier below the rounding floor is noise,
    # whatever the QR sweeps make of its modulus
    phase_known = moduli > 100.0 * noise
    reliable_all = bool(phase_known.all())
    if small_multipliers == "qr" and prop.factors is not None and not reliable_all:
        spec, digits = _qr_small_multipliers(spec, digits, prop.factors, noise)
        reliable_all = bool(np.all(digits > 0))
    certified, reasons = _certify(spec, prop, rtol, accuracy, phase_known, n_steps is None, method)
    multiplier_liouville = _liouville(float(spec.log_moduli.sum()), trace) if reliable_all else math.nan
    if reliable_all:
        liouville, liouville_source = multiplier_liouville, "multipliers"
    elif math.isfinite(prop.log_abs_det) and method != "paper":
        liouville, liouville_source = _liouville(prop.log_abs_det, trace), "propagators"
    else:
        # the paper's procedure keeps no propagators and det Phi of the formed matrix is
        # rounding noise when some multiplier is below the noise floor: nothing to check
        liouville, liouville_source = math.nan, "unavailable"
    tol = stability_tol
    if math.isfinite(prop.error_estimate):
        tol = max(tol, prop.error_estimate * rho)
    result = FloquetResult(
        multipliers=spec.values,
        log_moduli=spec.log_moduli,
        monodromy=prop.monodromy if scale is None else prop.monodromy * scale[:, None] / scale[None, :],
        spectral_radius=rho,
        verdict=_verdict(rho, tol),
        stability_tolerance=tol,
        liouville_residual=liouville,
        liouville_source=liouville_source,
        multiplier_liouville_residual=multiplier_liouville,
        trace_integral=trace,
        error_estimate=prop.error_estimate,
        noise_floor=noise,
        reliable_digits=digits,
        method=method,
        n_steps=prop.n_steps,
        n_evaluations=prop.n_evaluations,
        period=T,
        elapsed=time.perf_counter() - t0,
        accuracy=accuracy,
        phase_error_estimate=prop.phase_error_estimate,
        companion_steps=tuple(int(N) for N, _ in prop.companions),
        companion_monodromies=tuple(Phi if scale is None else Phi * scale[:, None] / scale[None, :]
                                    for _, Phi in prop.companions),
        rtol=float(rtol),
        certified=certified,
        uncertified_reasons=reasons,
        phase_known=phase_known,
        observed_order=float(prop.observed_order),
        breakpoints=tuple(breakpoints),
    )
    logger.debug(
        "floquet(%s): rho=%.6g steps=%d est=%.2e liouville=%.2e",
        method, rho, prop.n_steps, prop.error_estimate, liouville,
    )
    return result
