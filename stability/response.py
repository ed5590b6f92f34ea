"""Time response of a linear T-periodic system ``x' = P(t) x (+ f(t))``.

Public entry points:

:func:`linear_response`
    Integrates the paper's Eq. (3) (``forcing`` given) or its homogeneous
    part, Eq. (6)/(33) (``forcing=None``), from ``x(0) = x0`` with
    ``scipy.integrate.solve_ivp`` (Radau with the exact Jacobian ``P(t)``
    when ``P`` is stiff, DOP853 otherwise) and samples the solution on a grid
    that contains every multiple ``kT`` of the period.
:func:`points_per_period`
    A sampling density that resolves the fastest oscillation of ``P(t)``.
:func:`per_period_growth`
    Measures the per-period growth of a homogeneous response from its samples
    at ``t = kT``, to be compared with the dominant Floquet multiplier.
:func:`envelope_constant`
    The constant ``C`` of the envelope ``C |rho|^(t/T)`` that hugs the peaks
    of one response component.

Maths
-----
For ``x' = P(t) x`` with monodromy matrix ``Phi(T)`` the solution satisfies
``x((k+1)T) = Phi(T) x(kT)``, so ``x(kT) = Phi(T)^k x0``.  If the dominant
multiplier ``rho_1`` is real and simple, ``|rho_1| > |rho_2|``, then
``x((k+1)T) = rho_1 x(kT) + O(|rho_2 / rho_1|^k)``: the per-period ratio
``||x((k+1)T)|| / ||x(kT)||`` tends to ``|rho_1|`` geometrically with factor
``|rho_2 / rho_1|`` (the power method).  Between the sampling instants the
dominant Floquet solution is ``p_1(t) rho_1^(t/T)`` with a T-periodic
``p_1``, so each component of the response is eventually bounded by the
envelope ``C |rho_1|^(t/T)`` with ``C = max |p_1|`` (touched once per
period at the peaks).

References
----------
.. [1] Dat, D. C., Khang, N. V., Hoang, N. Q., Quyen, N. V., *Stability
   Control of Dynamical Systems Described by Linear Differential Equations
   with Time-Periodic Coefficients*, Eqs. (3), (6), (25), (33).
.. [2] Yakubovich, V. A., Starzhinskii, V. M., *Linear Differential
   Equations with Periodic Coefficients*, Wiley, 1975, Ch. II.
.. [3] Hairer, E., Wanner, G., *Solving Ordinary Differential Equations II*,
   Springer, 1996, Sec. IV.8 (Radau IIA).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np

from stability.periodic import check_period

__all__ = [
    "LinearResponse",
    "GrowthEstimate",
    "linear_response",
    "per_period_growth",
    "envelope_constant",
    "DEFAULT_RTOL",
    "DEFAULT_ATOL",
    "DEFAULT_POINTS_PER_PERIOD",
    "STIFF_DECAY_PER_PERIOD",
    "choose_method",
    "points_per_period",
]

#: Relative tolerance of ``solve_ivp``; well below the 1e-3 level at which the
#: measured per-period ratios are compared with the Floquet multipliers.
DEFAULT_RTOL = 1e-9
#: Absolute tolerance of ``solve_ivp``, as a fraction of the initial-state
#: size ``max(||x0||_inf, ||f||_inf over one period)``: the responses of
#: interest decay at most to ~1e-4 of that size over the plotted periods.
DEFAULT_ATOL = 1e-12
#: Output samples per period (dense-output interpolation between steps).
DEFAULT_POINTS_PER_PERIOD = 400
#: Integration methods that use the Jacobian ``P(t)``.
_IMPLICIT = ("Radau", "BDF", "LSODA")
#: ``method="auto"`` calls the system stiff when some eigenvalue of ``P(t)``
#: decays by more than ``exp(-STIFF_DECAY_PER_PERIOD)`` per period: such a
#: component is invisible in the response, yet an explicit method would have
#: to resolve it for stability alone.  (The uncontrolled manipulator, whose
#: fast eigenvalues are a lightly damped pair ``-0.55 +- 673i``/s, is not
#: stiff; with PD control a real eigenvalue near ``-3200``/s appears.)
STIFF_DECAY_PER_PERIOD = 100.0
#: Sample times per period at which ``method="auto"`` inspects ``P(t)``.
_STIFFNESS_PROBES = 8


@dataclass(frozen=True)
class LinearResponse:
    """Sampled solution of ``x' = P(t) x (+ f(t))``, ``x(0) = x0``.

    Attributes
    ----------
    t : ndarray, shape (m,)
        Sample times from 0 to ``t_end``; ``t[k * n_per_period] == k * period``
        exactly (in floating point) for every full period.
    x : ndarray, shape (m, n)
        The state at ``t``.
    homogeneous : bool
        ``True`` when no forcing was applied (paper Eq. 6/25/33).
    x0 : ndarray, shape (n,)
    t_end : float
    period : float
        The period ``T`` of ``P`` (and ``f``).
    n_per_period : int
        Samples per period.
    method : str
        The ``solve_ivp`` method used (``"auto"`` resolved).
    rtol, atol : float
        Tolerances actually passed to ``solve_ivp``.
    nfev, njev, nlu : int
        Right-hand-side and Jacobian evaluations and LU factorisations.
    elapsed : float
        Wall time in seconds.
    """

    t: np.ndarray
    x: np.ndarray
    homogeneous: bool
    x0: np.ndarray
    t_end: float
    period: float
    n_per_period: int
    method: str
    rtol: float
    atol: float
    nfev: int
    njev: int
    nlu: int
    elapsed: float = 0.0

    @property
    def n_full_periods(self) -> int:
        """Number of complete periods in ``[0, t_end]``."""
        return (len(self.t) - 1) // self.n_per_period

    def period_indices(self) -> np.ndarray:
        """Indices ``i`` with ``t[i] = k T``, ``k = 0 .. n_full_periods``."""
        return np.arange(self.n_full_periods + 1) * self.n_per_period

    def at_periods(self) -> np.ndarray:
        """States ``x(kT)``, shape ``(n_full_periods + 1, n)``."""
        return self.x[self.period_indices()]


@dataclass(frozen=True)
class GrowthEstimate:
    """Per-period growth of a response measured from its samples at ``t = kT``.

    Attributes
    ----------
    ratios : ndarray, shape (K,)
        ``||x((k+1)T)|| / ||x(kT)||`` for ``k = 0 .. K-1`` (Euclidean norm of
        the full state).
    fitted : float
        ``exp(slope)`` of the least-squares line through
        ``(k, ln ||x(kT)||)`` for ``k >= skip``; NaN with fewer than two points.
    peak_ratios : ndarray, shape (K - 1,)
        ``max_{[kT,(k+1)T]} ||x|| / max_{[(k-1)T,kT]} ||x||`` for ``k >= 1``
        (peak amplitude over consecutive periods after the first).
    skip : int
        Periods left out of ``fitted`` (the initial transient).
    """

    ratios: np.ndarray
    fitted: float
    peak_ratios: np.ndarray
    skip: int

    @property
    def last_ratio(self) -> float:
        """The last per-period ratio (the most converged one)."""
        return float(self.ratios[-1]) if len(self.ratios) else math.nan


def _validated_state(x0: Any) -> np.ndarray:
    x0 = np.array(x0, dtype=float)
    if x0.ndim != 1 or x0.size == 0:
        raise ValueError(f"x0 must be a non-empty 1-D vector, got shape {x0.shape}")
    if not np.all(np.isfinite(x0)):
        raise ValueError("x0 contains NaN or inf")
    return x0


def choose_method(P: Callable[[float], np.ndarray], period: float) -> str:
    """The ``solve_ivp`` method ``method="auto"`` uses for ``P``.

    Parameters
    ----------
    P : callable
        ``t -> (n, n)``, T-periodic.
    period : float
        ``T``.

    Returns
    -------
    str
        ``"Radau"`` (implicit, 5th order, L-stable, exact Jacobian) when
        ``max_t max_i (-Re lambda_i(P(t))) * T > STIFF_DECAY_PER_PERIOD`` on
        ``_STIFFNESS_PROBES`` equally spaced times; otherwise ``"DOP853"``
        (explicit, 8th order), which on the lightly damped, fast oscillatory
        uncontrolled manipulator is about ten times cheaper than Radau at the
        same tolerance.
    """
    T = check_period(period)
    decay = 0.0
    for s in np.arange(_STIFFNESS_PROBES) * (T / _STIFFNESS_PROBES):
        lam = np.linalg.eigvals(np.asarray(P(float(s)), dtype=float))
        decay = max(decay, float(np.max(-lam.real)))
    return "Radau" if decay * T > STIFF_DECAY_PER_PERIOD else "DOP853"


def points_per_period(
    P: Callable[[float], np.ndarray],
    period: float,
    *,
    per_cycle: int = 24,
    minimum: int = DEFAULT_POINTS_PER_PERIOD,
) -> int:
    """Samples per period that resolve the fastest oscillation of ``P(t)``.

    Parameters
    ----------
    P : callable
        ``t -> (n, n)``, T-periodic.
    period : float
        ``T``.
    per_cycle : int
        Samples per cycle of the fastest frozen-time oscillation
        ``max_t max_i |Im lambda_i(P(t))|`` (>= 2).
    minimum : int
        Lower bound on the result.

    Returns
    -------
    int
        ``max(minimum, ceil(per_cycle * max|Im lambda| * T / (2 pi)))``.

    Notes
    -----
    Plotting only: the integration accuracy does not depend on the sampling
    (see :func:`linear_response`).  The uncontrolled manipulator has an
    elastic pair near ``673i``/s, i.e. about 107 cycles per second.
    """
    T = check_period(period)
    if per_cycle < 2:
        raise ValueError(f"per_cycle must be >= 2, got {per_cycle!r}")
    omega = 0.0
    for s in np.arange(_STIFFNESS_PROBES) * (T / _STIFFNESS_PROBES):
        lam = np.linalg.eigvals(np.asarray(P(float(s)), dtype=float))
        omega = max(omega, float(np.max(np.abs(lam.imag))))
    return max(int(minimum), int(math.ceil(per_cycle * omega * T / (2.0 * math.pi))))


def linear_response(
    P: Callable[[float], np.ndarray],
    x0: Any,
    t_end: float,
    *,
    forcing: Optional[Callable[[float], np.ndarray]] = None,
    n_per_period: int = DEFAULT_POINTS_PER_PERIOD,
    period: Optional[float] = None,
    method: str = "auto",
    rtol: float = DEFAULT_RTOL,
    atol: Optional[float] = None,
) -> LinearResponse:
    """Integrate ``x' = P(t) x + f(t)`` (or ``x' = P(t) x``) from ``x(0) = x0``.

    Parameters
    ----------
    P : callable
        ``t -> (n, n)`` array, T-periodic (e.g.
        :class:`~mbs_models.reduced.ReducedModel`, whose ``.period`` is used
        when ``period`` is not given).
    x0 : array_like, shape (n,)
        Initial state (paper Eqs. 26/35: ``[0, 0, pi/4, 0]``).
    t_end : float
        End time (> 0).
    forcing : callable, optional
        ``t -> (n,)``, the vector ``f(t)`` of Eq. (3), e.g.
        ``model.forcing_first_order``.  ``None`` (default): the homogeneous
        system Eq. (6)/(33).
    n_per_period : int
        Output samples per period (>= 2); the grid contains every ``kT``.
    period : float, optional
        ``T > 0``; default ``P.period``.
    method : str
        ``"auto"`` (default: :func:`choose_method`, Radau for stiff ``P``,
        DOP853 otherwise) or a ``solve_ivp`` method; the implicit ones
        (``"Radau"``, ``"BDF"``, ``"LSODA"``) receive the exact Jacobian
        ``P(t)``.
    rtol : float
        Relative tolerance (default :data:`DEFAULT_RTOL`).
    atol : float, optional
        Absolute tolerance; default :data:`DEFAULT_ATOL` times
        ``max(||x0||_inf, max ||f||_inf over one period)``.

    Returns
    -------
    LinearResponse

    Raises
    ------
    ValueError
        On a bad shape, a non-finite input, ``t_end <= 0``, a missing or bad
        period, or ``n_per_period < 2``.
    RuntimeError
        If ``solve_ivp`` fails.

    Notes
    -----
    The output is the dense-output interpolant of the integrator evaluated
    on the grid ``t_i = T * (i / n_per_period)`` (plus ``t_end`` when it is
    not on the grid), so the sampling density does not influence the
    accuracy of the integration itself.

    Examples
    --------
    >>> import numpy as np
    >>> r = linear_response(lambda t: np.array([[-1.0]]), [1.0], 2.0, period=1.0, n_per_period=4)
    >>> float(abs(r.x[-1, 0] - np.exp(-2.0))) < 1e-8
    True
    """
    t0 = time.perf_counter()
    x0 = _validated_state(x0)
    n = x0.size
    if period is None:
        if not hasattr(P, "period"):
            raise ValueError("period is required when P has no .period attribute")
        period = P.period  # type: ignore[attr-defined]
    T = check_period(period)
    try:
        t_end = float(t_end)
    except (TypeError, ValueError):
        raise ValueError(f"t_end must be a real number, got {t_end!r}") from None
    if not math.isfinite(t_end) or t_end <= 0.0:
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    if isinstance(n_per_period, bool) or int(n_per_period) != n_per_period or n_per_period < 2:
        raise ValueError(f"n_per_period must be an integer >= 2, got {n_per_period!r}")
    n_per_period = int(n_per_period)
    P0 = np.asarray(P(0.0), dtype=float)
    if P0.shape != (n, n):
        raise ValueError(f"P(0) has shape {P0.shape}, expected {(n, n)} to match x0")
    if method == "auto":
        method = choose_method(P, T)
    if not (math.isfinite(rtol) and rtol > 0):
        raise ValueError(f"rtol must be finite and > 0, got {rtol!r}")

    scale = float(np.max(np.abs(x0)))
    if forcing is not None:
        f0 = np.asarray(forcing(0.0), dtype=float)
        if f0.shape != (n,):
            raise ValueError(f"forcing(0) has shape {f0.shape}, expected {(n,)}")
        probe = np.linspace(0.0, T, 17)
        scale = max(scale, max(float(np.max(np.abs(forcing(s)))) for s in probe))
    if atol is None:
        atol = DEFAULT_ATOL * (scale if scale > 0 else 1.0)
    if not (math.isfinite(atol) and atol > 0):
        raise ValueError(f"atol must be finite and > 0, got {atol!r}")

    if forcing is None:

        def rhs(t: float, x: np.ndarray) -> np.ndarray:
            return P(t) @ x

    else:

        def rhs(t: float, x: np.ndarray) -> np.ndarray:
            return P(t) @ x + forcing(t)

    n_samples = int(math.floor(t_end / T * n_per_period + 1e-9))
    grid = T * (np.arange(n_samples + 1) / n_per_period)
    grid = grid[grid <= t_end]
    if grid[-1] < t_end:
        grid = np.append(grid, t_end)

    from scipy.integrate import solve_ivp  # on first use: scipy.integrate costs ~0.3 s of imports

    kwargs = {"jac": lambda t, x: P(t)} if method in _IMPLICIT else {}
    sol = solve_ivp(
        rhs,
        (0.0, t_end),
        x0,
        method=method,
        t_eval=grid,
        rtol=rtol,
        atol=atol,
        **kwargs,
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp ({method}) failed: {sol.message}")
    return LinearResponse(
        t=sol.t,
        x=sol.y.T.copy(),
        homogeneous=forcing is None,
        x0=x0,
        t_end=t_end,
        period=T,
        n_per_period=n_per_period,
        method=method,
        rtol=float(rtol),
        atol=float(atol),
        nfev=int(sol.nfev),
        njev=int(sol.njev),
        nlu=int(sol.nlu),
        elapsed=time.perf_counter() - t0,
    )


def per_period_growth(response: LinearResponse, *, skip: int = 1) -> GrowthEstimate:
    """Measured per-period growth of a (homogeneous) response.

    Parameters
    ----------
    response : LinearResponse
        Should be homogeneous: a forced response tends to the forced periodic
        solution, whose per-period ratio is 1, not ``|rho_1|``.
    skip : int
        Number of initial periods left out of the least-squares fit (>= 0).

    Returns
    -------
    GrowthEstimate

    Raises
    ------
    ValueError
        If the response covers less than one full period or ``skip < 0``.

    Notes
    -----
    Maths: for a simple, real dominant multiplier the ratios converge to
    ``|rho_1|`` like ``|rho_2 / rho_1|^k`` (see the module docstring), so the
    later ratios are the better estimates.
    """
    if skip < 0:
        raise ValueError(f"skip must be >= 0, got {skip!r}")
    K = response.n_full_periods
    if K < 1:
        raise ValueError("the response covers less than one full period")
    norms = np.linalg.norm(response.at_periods(), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = norms[1:] / norms[:-1]
    ks = np.arange(skip, K + 1)
    if len(ks) >= 2 and np.all(norms[ks] > 0):
        slope = np.polyfit(ks, np.log(norms[ks]), 1)[0]
        fitted = float(np.exp(slope))
    else:
        fitted = math.nan
    n = response.n_per_period
    state_norm = np.linalg.norm(response.x, axis=1)
    peaks = np.array([np.max(state_norm[k * n : (k + 1) * n + 1]) for k in range(K)])
    with np.errstate(divide="ignore", invalid="ignore"):
        peak_ratios = peaks[1:] / peaks[:-1]
    return GrowthEstimate(ratios=ratios, fitted=fitted, peak_ratios=peak_ratios, skip=int(skip))


def envelope_constant(
    t: np.ndarray,
    y: np.ndarray,
    modulus: float,
    period: float,
    *,
    t_from: float,
    t_to: Optional[float] = None,
) -> float:
    """``C`` of the envelope ``C |rho|^(t/T)`` fitted to the peaks of ``y``.

    Parameters
    ----------
    t, y : ndarray, shape (m,)
        Sample times and one response component.
    modulus : float
        ``|rho_1|`` of the dominant multiplier (> 0).
    period : float
        ``T``.
    t_from, t_to : float
        Window of the fit (default ``t_to``: the end of the samples).

    Returns
    -------
    float
        ``max |y(t)| |rho|^(-t/T)`` over the window: the peak amplitude of the
        periodic factor of the dominant Floquet solution once the other
        solutions have died out relative to it.  Over a full period in that
        regime the envelope touches the highest peak of each period.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if not (math.isfinite(modulus) and modulus > 0):
        raise ValueError(f"modulus must be finite and > 0, got {modulus!r}")
    T = check_period(period)
    t_to = float(t[-1]) if t_to is None else float(t_to)
    mask = (t >= t_from) & (t <= t_to)
    if not np.any(mask):
        raise ValueError(f"no samples in the window [{t_from}, {t_to}]")
    return float(np.max(np.abs(y[mask]) * modulus ** (-t[mask] / T)))
