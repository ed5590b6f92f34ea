"""Floquet multipliers measured from nonlinear Exudyn runs.

The check that can fail a wrong prediction: instead of fitting the decay of
one coordinate, the one-period map of the nonlinear closed loop is measured
on the subspace of the multipliers under test, and its eigenvalues are
compared with the predicted multipliers in modulus and phase, within the
measurement's own error bar.

Method
------
1. **Directions.**  The prediction's monodromy ``Phi`` (linearisation along
   the orbit) gives right and left eigenvectors ``v_i``, ``w_i`` of the ``k``
   compared multipliers (real and imaginary parts for a complex pair, so the
   subspace is real, dimension ``k``).  Every direction is scaled to the same
   energy ``||d||_E = a sqrt(M_00)`` (the energy of a hub-velocity kick of
   ``a`` rad/s), with ``||x||_E^2 = p^T |K| p + v^T M v``, ``M, K`` of the
   linearisation at ``t = 0`` (``|K|`` the matrix absolute value in the
   ``M`` metric: the energy norm also when gravity makes ``K`` indefinite).
2. **Runs.**  Exudyn's generalised-alpha with ``spectralRadius = 1`` (no
   numerical damping of the modes compared) integrates one period from the
   orbit state ``x_0`` perturbed by ``+d_j`` and ``-d_j``; the column
   ``X_1[:, j] = (x_+(T) - x_-(T)) / 2`` is the image of ``d_j`` (the mean of
   the two perturbed-minus-reference differences: the reference run's own
   integration error cancels, and the central difference removes the
   quadratic term of the nonlinear map, leaving ``O(a^2)`` instead of
   ``O(a)``: measured at Omega = 2 pi, kp = 10, kd = 2 the one-sided
   difference moved the pair by 2.6e-6 per 1e-3 rad/s of amplitude).
3. **Projection.**  ``A = (W^T X_0)^{-1} W^T X_1`` (Petrov-Galerkin with the
   predicted left vectors ``W``), ``k x k``; its eigenvalues are the measured
   multipliers.  Why not the plain least-squares ``A = X_0^+ X_1``: the
   predicted vectors are not exactly invariant under Exudyn's discrete map;
   the leftover components along the other modes (undamped axial modes near
   the unit circle, badly resolved by the time step) enter the Galerkin
   eigenvalues at first order, the Petrov-Galerkin ones at second order
   (product of left and right vector errors).  Measured at Omega = 8 pi,
   Table 3 gains, h = 2.5e-4: Galerkin 0.394652, Petrov-Galerkin 0.394573,
   with the Petrov-Galerkin values converging monotonically in h and the
   Galerkin ones not.  The least-squares value is still reported
   (``galerkin``) as a diagnostic.  DMD over several periods was not chosen:
   the compared multipliers (|rho| ~ 0.05-0.4) die out against the undamped
   modes (|rho| ~ 1) within a few periods.
4. **Step convergence.**  The same at ``h, h/2, h/4`` (``refinements``
   halvings).  Reported value: the Richardson extrapolation of the three
   levels with the observed ratio (the finest level when fewer levels or no
   convergence).  Error bar ``step_error``:
   with three levels, Richardson with the observed ratio
   ``q = |mu_h - mu_h/2| / |mu_h/2 - mu_h/4|`` (capped at 4, the formal order 2):
   ``1.25 |mu_h/2 - mu_h/4| / (q - 1)``
   (the error of the finest value for a method converging as ``q^-j``, with
   the safety factor 1.25 of Roache's grid convergence index); with
   two levels (no observed order) ``|mu_h - mu_h/2|`` itself is reported, but
   the measurement counts as not converged (no verdict: two levels cannot show
   that the method is in its asymptotic range).  A ratio ``q < 1.1`` (no
   convergence seen) is flagged and the bar set to ``max(d1, d2) * 10`` --
   unless both changes are below :data:`STEP_FLOOR` of the compared modulus
   (the levels agree to the runs' resolution: converged, same bar).  A finest
   change of exactly 0 (``q = inf``) gets the same ``10 max(d1, d2)`` bar,
   never 0.
5. **Linear range by evidence.**  The finest level is repeated with the
   amplitude halved; ``amplitude_check`` reports the change.  With central
   differences the amplitude error is ``c a^2``, so the error of the reported
   value is ``4/3 |mu(a) - mu(a/2)|`` (added to the error bar as
   ``amplitude_error``); the check passes when the change is within the
   step error bar.  The finest level, not the coarsest: the change also
   carries the Newton error of the runs that does not cancel between the
   ``+`` and ``-`` runs (relative to the signal ~ 1/a), which grows as the
   step shrinks (measured on the Kapitza pendulum, rho_inf = 1, a = 1e-2:
   coarsest-level change 1.7e-6, finest-level error 5e-6 against Mathieu).
6. **Verdict.**  A multiplier agrees iff
   ``|mu_measured - mu_predicted| <= step_error + amplitude_error + prediction_error``
   and the step refinement converges; the prediction is the linearisation's
   monodromy with its exponential-midpoint propagator refined by step doubling
   until the compared multipliers move by less than 1e-6 relative, the last
   change being the prediction error (:func:`_refined_prediction`).  Only
   modes the integrator resolves at the finest step are compared
   (:data:`RESOLUTION_PHASE`).  Alternatives (the reduced model, the
   linearisation about the rigid reference) are reported with their distance
   to the measurement and whether the measurement is consistent with them.

Model files (:func:`validate_model_multipliers`) go through the generic path
(:func:`linearize.analysis.analyze`): the drives are released and driven by
feed-forward + PD inside Exudyn, perturbations enter through the null-space
basis of the linearisation.

Divergence: a failing Exudyn run, a non-finite state or a perturbation image
far beyond the linear range is reported (``diverged``, when, why); nothing
raises for a diverging run.

Uncontrolled loops: :func:`measure_growth` follows ``x_0 +- d`` and the
reference over several periods and reports the per-period growth of the
central difference in the energy norm, and the nonlinearity indicator
``||x_+ + x_- - 2 x_ref||_E / ||x_+ - x_-||_E`` (zero for a linear map); the
linear range is left at the first period where it exceeds
:data:`LINEAR_RANGE_TOLERANCE`.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Optional, Sequence

import numpy as np

from stability.frozen import frozen_result
from stability.serialization import json_ready

__all__ = [
    "DEFAULT_AMPLITUDE",
    "LINEAR_RANGE_TOLERANCE",
    "MULTIPLIER_FLOOR",
    "Alternative",
    "EnergyNorm",
    "GrowthResult",
    "MultiplierCheckConfig",
    "MultiplierValidation",
    "Prediction",
    "energy_norm",
    "measure_growth",
    "measure_multipliers",
    "prediction_from_monodromy",
    "prediction_from_multipliers",
    "validate_model_multipliers",
]

logger = logging.getLogger(__name__)

#: Perturbation amplitude, as the hub-velocity kick (rad/s) of the same
#: energy.  Measured at Omega = 2 pi, kp = 10, kd = 2 (4 elements): the
#: one-sided difference moves the pair by 2.6e-6 at 1e-3 and the central
#: difference removes that first-order term; Newton's tolerance (1e-8
#: relative on coordinates of order 1) over 1e-3 gives ~1e-5 relative noise
#: at worst, far below the compared differences.
DEFAULT_AMPLITUDE = 1e-3
#: Perturbation amplitude of the model-file path (generic constrained coordinates).  A margin
#: against Newton errors that do not cancel between the + and - runs (relative to the signal
#: ~1/a; see :data:`MODEL_NEWTON_TOLERANCE`) at no cost in linearity: on the 4-element single
#: link (2 pi, Table 3 gains) the quadratic term left by the central difference is 7e-8 at 3e-2
#: against 1e-2, i.e. ~8e-9 at 1e-2.
MODEL_AMPLITUDE = 1e-2
#: Multipliers below this modulus are not compared: one-period differences
#: of amplitude ~1e-3 resolve ~1e-8 absolute, and a multiplier of 1e-6 has
#: no digit left to compare (e.g. the hub-rate mode, rho ~ exp(-kd T / J1)).
MULTIPLIER_FLOOR = 1e-6
#: Nonlinearity indicator beyond which the motion has left the linear range
#: (:func:`measure_growth`): the quadratic part of the map is 1 % of the
#: linear part.
LINEAR_RANGE_TOLERANCE = 1e-2
#: A perturbation image larger than this many times the orbit's own energy
#: scale is called diverged (the linearisation is meaningless far beyond it).
DIVERGENCE_FACTOR = 1e6


# --------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class MultiplierCheckConfig:
    """Settings of the multiplier measurement.

    Parameters
    ----------
    compare : int
        Number ``k`` of multipliers compared (>= 1; a complex pair counts two
        and is never split: ``k`` is raised by one if needed).
    step : float or None
        Coarsest generalised-alpha step (s).  ``None``: chosen by the path --
        :func:`suggested_step` of the linearisation.
    refinements : int
        Step halvings (0: ``h`` only, no error bar; 1: ``h, h/2``, a bar but no verdict: two levels
        show no convergence order; 2: ``h, h/2, h/4``, the least for a verdict).
    amplitude : float or None
        Perturbation energy as a hub-velocity kick (rad/s), > 0.  ``None``:
        :data:`DEFAULT_AMPLITUDE` for the built-in link, :data:`MODEL_AMPLITUDE`
        for model files.
    amplitude_check : bool
        Repeat the finest level with half the amplitude.
    growth_periods : int
        Periods of the multi-period growth run (0: none).
    spectral_radius : float
        Generalised-alpha ``rho_inf`` in [0, 1]; default 1 (no numerical damping of
        the modes compared).  Models with index-3 constraints carrying large
        reactions may need a value slightly below 1: generalised-alpha at
        ``rho_inf = 1`` does not damp the spurious oscillation of the Lagrange
        multipliers (Arnold & Bruls 2007); measured on the vibration-stabilised
        inverted pendulum (support acceleration 32 g): the measured pair stalls
        at ~2e-4 from the Mathieu multipliers and the levels wander under step
        halving at 1, converges as h^2 (error 9.3e-4, 1.9e-4, 4.6e-5, 1.2e-5) at
        0.95.  The step-convergence check flags the former
        (``step_converged = False``).
    """

    compare: int = 2
    step: Optional[float] = 1e-3
    refinements: int = 2
    amplitude: Optional[float] = DEFAULT_AMPLITUDE
    amplitude_check: bool = True
    growth_periods: int = 0
    spectral_radius: float = 1.0

    def __post_init__(self) -> None:
        if not (0.0 <= float(self.spectral_radius) <= 1.0):
            raise ValueError(f"spectral_radius must be in [0, 1], got {self.spectral_radius!r}")
        object.__setattr__(self, "spectral_radius", float(self.spectral_radius))
        if isinstance(self.compare, bool) or int(self.compare) != self.compare or self.compare < 1:
            raise ValueError(f"compare must be an integer >= 1, got {self.compare!r}")
        if isinstance(self.refinements, bool) or int(self.refinements) != self.refinements or not 0 <= self.refinements <= 4:
            raise ValueError(f"refinements must be an integer in 0..4, got {self.refinements!r}")
        if isinstance(self.growth_periods, bool) or int(self.growth_periods) != self.growth_periods or self.growth_periods < 0:
            raise ValueError(f"growth_periods must be an integer >= 0, got {self.growth_periods!r}")
        for name in ("step", "amplitude"):
            if getattr(self, name) is None:
                continue
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        object.__setattr__(self, "compare", int(self.compare))
        object.__setattr__(self, "refinements", int(self.refinements))
        object.__setattr__(self, "growth_periods", int(self.growth_periods))

    @property
    def steps(self) -> tuple:
        """Step sizes ``h, h/2, ...`` (empty while ``step`` is ``None``)."""
        return step_halvings(self.step, self.refinements)


def step_halvings(step: Optional[float], refinements: int) -> tuple:
    """``(h, h/2, ..., h/2^refinements)``; empty while ``step`` is ``None`` (the step levels of both measurements)."""
    if step is None:
        return ()
    return tuple(step / 2**j for j in range(refinements + 1))


@dataclass(frozen=True)
class EnergyNorm:
    """``||x||_E^2 = p^T |K| p + v^T M v`` via Cholesky factors (``z = [Lk^T p; Lm^T v]``)."""

    Lk: np.ndarray
    Lm: np.ndarray
    hub_mass: float

    def transform(self, x: np.ndarray) -> np.ndarray:
        """``z`` with ``||z||_2 = ||x||_E`` (columns of a 2-D array are transformed each)."""
        n = self.Lm.shape[0]
        x = np.asarray(x)
        return np.concatenate([self.Lk.T @ x[:n], self.Lm.T @ x[n:]], axis=0)

    def norm(self, x: np.ndarray) -> float:
        return float(np.linalg.norm(self.transform(x)))


def energy_norm(M: np.ndarray, K: np.ndarray) -> EnergyNorm:
    """Energy norm from ``M`` (symmetric positive definite) and ``K`` (symmetric part used).

    ``|K|`` is the matrix absolute value of ``K`` in the ``M`` metric
    (eigenvalues of ``M^{-1} K`` replaced by their moduli, floored at 1e-12
    of the largest), so the norm exists when gravity or an uncontrolled hub
    make ``K`` indefinite or singular.
    """
    M = 0.5 * (np.asarray(M, dtype=float) + np.asarray(M, dtype=float).T)
    K = 0.5 * (np.asarray(K, dtype=float) + np.asarray(K, dtype=float).T)
    Lm = np.linalg.cholesky(M)
    Li = np.linalg.inv(Lm)
    lam, U = np.linalg.eigh(Li @ K @ Li.T)
    lam = np.maximum(np.abs(lam), 1e-12 * float(np.max(np.abs(lam))) if lam.size else 1.0)
    Kabs = Lm @ (U * lam) @ U.T @ Lm.T
    Lk = np.linalg.cholesky(0.5 * (Kabs + Kabs.T))
    return EnergyNorm(Lk=Lk, Lm=Lm, hub_mass=float(M[0, 0]))


@frozen_result
@dataclass(frozen=True)
class Prediction:
    """Multipliers under test with their right / left Floquet vectors.

    Attributes
    ----------
    name : str
        E.g. ``"exudyn orbit linearisation"``.
    multipliers : ndarray, complex, shape (k,)
        Compared multipliers (conjugate pairs complete), sorted by modulus.
    labels : tuple of str
        Mode label of each.
    right, left : ndarray, shape (2n, k)
        Real bases of the right and left invariant subspaces (``Re v, Im v``
        for a pair).
    errors : ndarray, shape (k,)
        Error estimate of each predicted multiplier (absolute).
    all_multipliers : ndarray, complex
        Every predicted multiplier (for the figure).
    info : dict
        E.g. ``propagator_steps`` of the refined monodromy.
    """

    name: str
    multipliers: np.ndarray
    labels: tuple
    right: np.ndarray = field(repr=False)
    left: np.ndarray = field(repr=False)
    errors: np.ndarray
    all_multipliers: np.ndarray = field(repr=False)
    info: dict = field(default_factory=dict)


def _select(multipliers: np.ndarray, labels: Sequence[str], allowed: Optional[Sequence[str]], k: int,
            undamped_tol: float) -> list:
    """Indices of the ``k`` largest multipliers that are compared (see :func:`prediction_from_monodromy`)."""
    mu = np.asarray(multipliers)
    cand = [i for i in np.argsort(-np.abs(mu), kind="stable")
            if abs(mu[i]) >= MULTIPLIER_FLOOR and abs(abs(mu[i]) - 1.0) >= undamped_tol
            and (labels[i] in allowed if allowed is not None else not labels[i].endswith("(unresolved)"))]
    chosen: list = []
    for i in cand:
        if len(chosen) >= k:
            break
        if i in chosen:
            continue
        chosen.append(i)
        if abs(mu[i].imag) > 1e-12 * max(abs(mu[i]), 1e-300):
            j = min((j for j in cand if j not in chosen), key=lambda j: abs(mu[j] - np.conj(mu[i])), default=None)
            if j is not None and abs(mu[j] - np.conj(mu[i])) <= 1e-8 * abs(mu[i]):
                chosen.append(j)
    return chosen


def prediction_from_multipliers(name: str, multipliers: Sequence[complex]) -> Prediction:
    """An alternative prediction given by its multipliers alone (e.g. a reduced model's), sorted by modulus.

    It carries no Floquet vectors: :func:`measure_multipliers` reports its distance to the
    measurement (:class:`Alternative`), it is never the prediction under test.
    """
    mu = np.asarray(multipliers, dtype=complex)
    mu = mu[np.argsort(-np.abs(mu), kind="stable")]
    return Prediction(name, mu, ("",) * mu.size, np.empty((0, 0)), np.empty((0, 0)), np.zeros(mu.size), mu.copy())


def prediction_from_monodromy(
    name: str,
    monodromy: np.ndarray,
    *,
    k: int = 2,
    labels: Optional[Sequence[str]] = None,
    allowed: Optional[Sequence[str]] = None,
    refined: Optional[np.ndarray] = None,
    undamped_tol: float = 2e-3,
) -> Prediction:
    """Compared multipliers and their Floquet vectors from a predicted monodromy matrix.

    Selection: the ``k`` largest multipliers (by modulus) that are above
    :data:`MULTIPLIER_FLOOR`, not on the unit circle within ``undamped_tol``
    (undamped structural modes: nothing to compare but the integrator's
    phase error) and, if ``allowed`` is given, whose label is in it; a
    complex pair is completed.  Fewer than ``k`` if fewer exist.

    Parameters
    ----------
    refined : ndarray, optional
        The monodromy by the same propagator with another number of steps
        (:func:`_refined_prediction`: half as many); the per-multiplier
        difference is the prediction's error estimate.
    """
    Phi = np.asarray(monodromy, dtype=float)
    mu, V = np.linalg.eig(Phi)
    muL, WL = np.linalg.eig(Phi.T)
    labels = list(labels) if labels is not None else [""] * mu.size
    if len(labels) != mu.size:
        # labels given in another order (e.g. sorted): match by value
        raise ValueError("labels must have one entry per multiplier of the monodromy")
    idx = _select(mu, labels, allowed, k, undamped_tol)
    if not idx:
        raise ValueError(f"{name}: no multiplier to compare (all on the unit circle or below {MULTIPLIER_FLOOR:g})")
    idx.sort(key=lambda i: (-abs(mu[i]), -mu[i].imag))
    R, L = [], []
    done: set = set()
    for i in idx:
        if i in done:
            continue
        j = int(np.argmin(np.abs(muL - mu[i])))
        v, w = V[:, i], WL[:, j]
        if abs(mu[i].imag) > 1e-12 * abs(mu[i]):
            R += [v.real, v.imag]
            L += [w.real, w.imag]
            done.update(ii for ii in idx if abs(mu[ii] - np.conj(mu[i])) <= 1e-8 * abs(mu[i]))
        else:
            R.append(v.real)
            L.append(w.real)
        done.add(i)
    errors = np.zeros(len(idx))
    if refined is not None:
        mu_r = np.linalg.eigvals(np.asarray(refined, dtype=float))
        errors = np.array([float(np.min(np.abs(mu_r - mu[i]))) for i in idx])
    return Prediction(
        name=name,
        multipliers=mu[idx].astype(complex),
        labels=tuple(labels[i] for i in idx),
        right=np.array(R).T,
        left=np.array(L).T,
        errors=errors,
        all_multipliers=mu.astype(complex),
    )


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Alternative:
    """Another prediction and its distance to the measurement."""

    name: str
    multipliers: np.ndarray
    distance: float
    consistent: bool

    def to_dict(self) -> dict:
        return {"name": self.name, "multipliers": [[float(z.real), float(z.imag)] for z in self.multipliers],
                "distance": self.distance, "consistent": self.consistent}


@dataclass(frozen=True)
class GrowthResult:
    """Multi-period run along the dominant direction (uncontrolled loops).

    Attributes
    ----------
    norms : ndarray
        ``||x_+(kT) - x_-(kT)||_E / 2`` for ``k = 0 .. periods_completed``.
    ratios : ndarray
        Per-period growth ``norms[k+1] / norms[k]``.
    nonlinearity : ndarray
        ``||x_+ + x_- - 2 x_ref||_E / ||x_+ - x_-||_E`` at ``k = 1 ..``.
    linear_periods : int
        Periods before the linear range was left (ratios inside it: ``ratios[:linear_periods]``).
    linear_range_left_at : float or None
        Time (s) of the first sample beyond :data:`LINEAR_RANGE_TOLERANCE`.
    measured_growth : float
        Geometric mean of the ratios inside the linear range (NaN if none).
    predicted : float
        ``|rho|`` of the dominant predicted multiplier.
    diverged : bool
    diverged_at : float or None
    reason : str
    """

    norms: np.ndarray
    ratios: np.ndarray
    nonlinearity: np.ndarray
    linear_periods: int
    linear_range_left_at: Optional[float]
    measured_growth: float
    predicted: float
    diverged: bool
    diverged_at: Optional[float]
    reason: str

    def to_dict(self) -> dict:
        return json_ready(dict(self.__dict__))


@frozen_result
@dataclass(frozen=True)
class MultiplierValidation:
    """Measured against predicted multipliers (see the module docstring).

    Attributes
    ----------
    prediction : Prediction
    measured : ndarray, complex, shape (k,)
        Measured multipliers, ordered as the prediction: Richardson-extrapolated
        from three converging step levels, else the finest step.
    levels : ndarray, complex, shape (levels, k)
        Measured multipliers per step ``config.steps``.
    galerkin : ndarray, complex, shape (k,)
        Least-squares (Galerkin) estimate at the finest step (diagnostic).
    step_error, amplitude_error, errors : ndarray, shape (k,)
        Error bars (absolute); ``errors = step_error + amplitude_error + prediction.errors``.
    observed_ratio : ndarray, shape (k,)
        ``|mu_h - mu_h/2| / |mu_h/2 - mu_h/4|`` (NaN with fewer than three levels).
    step_converged : bool
    amplitude_check : dict
        ``amplitude``, ``half``, ``change`` (per multiplier), ``passed``.
    alternatives : tuple of Alternative
    diverged : bool
    diverged_at : float or None
    reason : str
    agrees : bool
        The dominant multiplier (or pair) resolved and within its bar, every other
        *resolved* compared multiplier within its bar (:attr:`resolved`), no divergence;
        unresolved ones are listed (``unresolved`` in the JSON), not judged.
    growth : GrowthResult or None
    info : dict
        Model, omega, gains, elements, period, timings.
    config : MultiplierCheckConfig
    orbit : PeriodicOrbit or None
        The orbit the runs started from (built-in link; reusable for other gains).
    converged : ndarray of bool, shape (k,)
        Step refinement converging, per multiplier.
    agrees_dominant : bool
        The verdict restricted to the dominant multiplier (or pair).
    agrees_all : bool
        Every compared multiplier resolved and within its bar (``step_converged`` and no
        divergence).
    """

    prediction: Prediction
    measured: np.ndarray
    levels: np.ndarray
    galerkin: np.ndarray
    step_error: np.ndarray
    amplitude_error: np.ndarray
    errors: np.ndarray
    observed_ratio: np.ndarray
    step_converged: bool
    amplitude_check: dict
    alternatives: tuple
    diverged: bool
    diverged_at: Optional[float]
    reason: str
    agrees: bool
    growth: Optional[GrowthResult]
    info: dict
    config: MultiplierCheckConfig
    orbit: Any = field(default=None, repr=False)
    converged: Optional[np.ndarray] = None
    agrees_dominant: bool = False
    agrees_all: bool = False

    @property
    def resolved(self) -> np.ndarray:
        """Per compared multiplier: resolved by the measurement (the criterion of the verdict).

        Resolved = the step levels converge (observed ratio >= 1.1, or all changes below
        :data:`STEP_FLOOR`) and the bar (step + amplitude) is below :data:`MEASURED_FRACTION`
        of the modulus.  Why a multiplier can be unresolved although the dominant one is
        measured to 1e-6: a small multiplier (e.g. 0.0042 at 6 pi, Table 3 gains) is contaminated
        at second order by the spurious one-period multipliers that generalised-alpha at
        ``rho_inf = 1`` leaves to strongly damped modes it does not resolve (see
        :func:`suggested_step`): ~1e-4 absolute at h = 1e-3 ... 2.5e-4 s, i.e. 3e-4 of the
        dominant 0.297 but 4 % of 0.0042 -- its levels wander (0.0042216, 0.0040617, 0.0042291)
        instead of converging.  Smaller steps resolve it (model-file link, T/2048 and below).
        """
        if self.converged is None or self.measured.size == 0:
            return np.zeros(self.prediction.multipliers.size, dtype=bool)
        return np.asarray(self.converged, dtype=bool)

    @property
    def confirms(self) -> list:
        """Names of the predictions the measurement is consistent with (tested one first)."""
        out = [self.prediction.name] if self.agrees else []
        return out + [a.name for a in self.alternatives if a.consistent]

    def per_multiplier(self) -> list:
        rows = []
        for i, (p, lab) in enumerate(zip(self.prediction.multipliers, self.prediction.labels)):
            row = {"predicted": [p.real, p.imag], "mode": lab, "prediction_error": self.prediction.errors[i]}
            if self.measured.size:
                m = self.measured[i]
                d = abs(m - p)
                dphase = float(np.angle(m / p)) if abs(p) > 0 and abs(m) > 0 else math.nan
                row.update({
                    "measured": [m.real, m.imag],
                    "abs_error": d,
                    "relative_error": d / abs(p),
                    "modulus_predicted": abs(p),
                    "modulus_measured": abs(m),
                    "modulus_error": abs(m) - abs(p),
                    "phase_predicted": float(np.angle(p)),
                    "phase_measured": float(np.angle(m)),
                    "phase_error": dphase,
                    "step_error": self.step_error[i],
                    "amplitude_error": self.amplitude_error[i],
                    "error_bar": self.errors[i],
                    "step_converged": bool(self.converged[i]) if self.converged is not None else None,
                    "agrees": bool(d <= self.errors[i] and (self.converged is None or self.converged[i])),
                    "levels": [[z.real, z.imag] for z in self.levels[:, i]],
                    "galerkin": [self.galerkin[i].real, self.galerkin[i].imag],
                })
            rows.append(row)
        return rows

    def to_dict(self) -> dict:
        c = lambda zs: [[float(z.real), float(z.imag)] for z in zs]  # noqa: E731
        d = dict(self.info)
        d.update({
            "prediction": self.prediction.name,
            "prediction_propagator_steps": self.prediction.info.get("propagator_steps"),
            "predicted_multipliers": c(self.prediction.multipliers),
            "measured_multipliers": c(self.measured),
            "multipliers": self.per_multiplier(),
            "step_error": self.step_error,
            "steps": list(self.config.steps),
            "observed_ratio": self.observed_ratio,
            "step_converged": self.step_converged,
            "amplitude_check": self.amplitude_check,
            "alternatives": [a.to_dict() for a in self.alternatives],
            "confirms": self.confirms,
            "diverged": self.diverged,
            "diverged_at": self.diverged_at,
            "reason": self.reason,
            "agrees": self.agrees,
            "agrees_dominant": self.agrees_dominant,
            "agrees_all": self.agrees_all,
            "unresolved": [{"predicted": [float(p.real), float(p.imag)], "mode": lab,
                            "levels": [[float(z.real), float(z.imag)] for z in self.levels[:, i]]
                            if self.levels.size else []}
                           for i, (p, lab, ok) in enumerate(zip(self.prediction.multipliers, self.prediction.labels,
                                                                 self.resolved)) if not ok],
            "resolved_criterion": ("step levels converging (observed ratio >= 1.1, or all changes below "
                                   f"{STEP_FLOOR:g} of the compared modulus) and step + amplitude bar <= "
                                   f"{MEASURED_FRACTION:g} of the modulus; the verdict judges resolved multipliers "
                                   "and requires the dominant one to be resolved"),
            "growth": None if self.growth is None else self.growth.to_dict(),
            "integrator": f"generalised-alpha, spectralRadius = {self.config.spectral_radius:g}"
                          + (" (no numerical damping)" if self.config.spectral_radius == 1.0 else ""),
            "spectral_radius": self.config.spectral_radius,
        })
        return json_ready(d)


# --------------------------------------------------------------------------- core
class _Diverged(Exception):
    def __init__(self, at: float, reason: str) -> None:
        super().__init__(reason)
        self.at = at
        self.reason = reason


def _images(period_map: Callable[[np.ndarray, float], np.ndarray], x0: np.ndarray, D: np.ndarray, h: float,
            scale: float, norm: EnergyNorm, t_start: float = 0.0) -> np.ndarray:
    """Central-difference images ``(x_+(T) - x_-(T)) / 2`` of the columns of ``D``."""
    cols = []
    for j in range(D.shape[1]):
        ends = []
        for sign in (1.0, -1.0):
            try:
                xe = period_map(x0 + sign * D[:, j], h)
            except Exception as exc:  # the simulator's own error types (solver failure, bad state)
                raise _Diverged(t_start, f"one-period run from t = {t_start:g} s along direction {j} "
                                         f"({'+' if sign > 0 else '-'}), step {h:g} s: {exc}") from None
            if not np.all(np.isfinite(xe)):
                raise _Diverged(t_start, f"non-finite state after the period from t = {t_start:g} s (direction {j}, step {h:g} s)")
            ends.append(xe)
        img = 0.5 * (ends[0] - ends[1])
        size = norm.norm(img) if np.all(np.isfinite(img)) else math.inf
        if size > DIVERGENCE_FACTOR * scale:
            raise _Diverged(t_start, f"perturbation grew to {size / scale:.3g} x its start (limit "
                                     f"{DIVERGENCE_FACTOR:g}) in the period from t = {t_start:g} s (direction {j}, step {h:g} s)")
        cols.append(img)
    return np.array(cols).T


def _eigs_matched(A: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Eigenvalues of ``A`` ordered to match ``target`` (assignment on |difference|)."""
    from scipy.optimize import linear_sum_assignment

    ev = np.linalg.eigvals(A)
    cost = np.abs(ev[:, None] - target[None, :])
    r, c = linear_sum_assignment(cost)
    out = np.empty(target.size, dtype=complex)
    out[c] = ev[r]
    return out


#: A multiplier counts as measured only if its step error bar is below this fraction of its modulus.
MEASURED_FRACTION = 0.1

#: Safety factor of the three-level step error (Roache's grid convergence index, observed order).
#: Measured need: Kapitza pendulum, h = T/128 ... T/512, ratio 4.25: the plain Richardson estimate
#: (1.06e-5) was 10 % below the true error of the finest level against Mathieu (1.17e-5).
GCI_SAFETY = 1.25
#: Step levels whose changes are all below this times the largest compared modulus are at the
#: resolution of the runs (Newton increments, round-off): converged, whatever their ratio.
#: Measured on the 4-element model-file link at 2 pi, T/8192 ... T/32768: 0.299812268, 260, 248
#: (changes 7e-9, 1.3e-8: ratio 0.57, i.e. scatter, not a trend); the agreement sought is 1e-3
#: to 1e-4 relative.
STEP_FLOOR = 1e-6
#: Error ratio per step halving of a second-order integrator (generalised-alpha): the observed
#: ratio used by the step error bar is capped at this (Roache: observed order <= formal order).
FORMAL_RATIO = 4.0


def _gci_bar(d0: float, d1: float, scale: float, floor: float = 0.0) -> tuple[float, float, Optional[float]]:
    """Error bar of the finest of three levels from its last two changes ``d0`` (coarser) and ``d1`` (finer).

    ``q = d0 / d1``.  With ``q >= 1.1``: Roache's GCI, ``GCI_SAFETY d1 / (min(q, FORMAL_RATIO) - 1)``, and the
    capped ratio is returned for the extrapolation.  Otherwise no ratio is used (``None``) and the bar is
    ``10 max(d0, d1)``: no convergence seen (``q < 1.1``), or the finest change vanished (``d1 == 0``,
    ``q = inf``: two equal values show no order, and the GCI would claim an error of exactly 0).  That
    bar is never below ``floor`` nor below ``10 eps scale`` (the resolution of values of size
    ``scale``): an error bar is never 0.

    Returns
    -------
    (bar, q, capped ratio or None)
    """
    q = d0 / d1 if d1 > 0 else math.inf
    if d1 > 0 and q >= 1.1:
        qe = min(q, FORMAL_RATIO)
        return GCI_SAFETY * d1 / (qe - 1.0), q, qe
    return max(10.0 * max(d0, d1), floor, 10.0 * np.finfo(float).eps * abs(scale)), q, None


def _step_error(levels: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step error bar, observed ratio, per-multiplier convergence and the reported value.

    See the module docstring, item 4.  With three converging levels the reported value is the
    Richardson extrapolation ``mu_h/4 + (mu_h/4 - mu_h/2) / (q - 1)`` and the bar is the GCI of
    the finest level (an upper estimate for the extrapolated value); otherwise the finest level.
    Three levels whose two changes are both below ``floor`` (the runs' resolution, see
    :data:`STEP_FLOOR`) count as converged whatever their ratio, with the bar ten times the
    larger change.
    """
    m, k = levels.shape
    ratio = np.full(k, math.nan)
    if m == 1:
        return np.full(k, math.nan), ratio, np.zeros(k, dtype=bool), levels[-1].copy()
    d1 = np.abs(levels[-2] - levels[-1])
    if m == 2:
        # two levels show no convergence order: the change is reported as the bar, but nothing counts as
        # converged (no verdict; three levels, refinements >= 2, are needed for one)
        return d1, ratio, np.zeros(k, dtype=bool), levels[-1].copy()
    d0 = np.abs(levels[-3] - levels[-2])
    err = np.empty(k)
    ok = np.ones(k, dtype=bool)
    value = levels[-1].copy()
    for i in range(k):
        # Roache's grid convergence index: safety factor 1.25 on the observed-order estimate,
        # the order capped at the integrator's formal one (a ratio above 4 -- e.g. a coarse
        # level still outside the asymptotic range, or two fine levels agreeing by chance --
        # would make the bar optimistic; measured on the model-file single link: 28)
        err[i], ratio[i], qe = _gci_bar(d0[i], d1[i], abs(levels[-1, i]), floor)
        if qe is not None:
            value[i] = levels[-1, i] + (levels[-1, i] - levels[-2, i]) / (qe - 1.0)
        elif d1[i] > 0:  # q < 1.1: no convergence seen, unless both changes are at the runs' resolution
            ok[i] = bool(max(d0[i], d1[i]) <= floor)
        # d1 == 0: the two finest levels agree (converged, as before), but with the bar 10 d0, never 0
    return err, ratio, ok, value


def measure_multipliers(
    period_map_factory: Callable[[float], Callable[[np.ndarray, float], np.ndarray]],
    x0: np.ndarray,
    prediction: Prediction,
    norm: EnergyNorm,
    config: MultiplierCheckConfig = MultiplierCheckConfig(),
    *,
    alternatives: Sequence[Prediction] = (),
    info: Optional[dict] = None,
    period: float = math.nan,
) -> MultiplierValidation:
    """Measure the compared multipliers from nonlinear one-period runs (model-independent core).

    Parameters
    ----------
    period_map_factory : callable
        ``h -> f`` where ``f(x, h)`` integrates the nonlinear closed loop over
        one period from the full independent state ``x = [p, p']`` at
        ``t = 0`` with step ``h`` and returns the state at ``t = T`` (it may
        raise on a solver failure: reported as a divergence).
    x0 : ndarray, shape (2n,)
        The periodic orbit's state at ``t = 0``.
    prediction : Prediction
        Multipliers under test and their vectors.
    norm : EnergyNorm
    config : MultiplierCheckConfig
    alternatives : sequence of Prediction
        Other predictions whose distance to the measurement is reported.
    info : dict, optional
        Copied into the JSON (model, gains, ...).
    period : float
        ``T`` (only reported).

    Returns
    -------
    MultiplierValidation
        Never raises for a diverging run (``diverged=True``).
    """
    if config.step is None or config.amplitude is None:
        raise ValueError("measure_multipliers needs config.step and config.amplitude (None is resolved by the "
                         "validate_* functions)")
    tic = time.perf_counter()
    info = dict(info or {})
    x0 = np.asarray(x0, dtype=float)
    pred = prediction.multipliers
    k = pred.size
    scale = config.amplitude * math.sqrt(norm.hub_mass)
    D = np.array([d / norm.norm(d) * scale for d in prediction.right.T]).T
    W = prediction.left
    levels, galerkin = [], None
    diverged, at, reason = False, None, ""
    amp_change = np.full(k, math.nan)
    timings: dict = {}
    try:
        for j, h in enumerate(config.steps):
            t1 = time.perf_counter()
            f = period_map_factory(h)
            X1 = _images(f, x0, D, h, scale, norm)
            A = np.linalg.solve(W.T @ D, W.T @ X1)
            levels.append(_eigs_matched(A, pred))
            if j == len(config.steps) - 1:
                Z0, Z1 = norm.transform(D), norm.transform(X1)
                galerkin = _eigs_matched(np.linalg.lstsq(Z0, Z1, rcond=None)[0], pred)
            if j == len(config.steps) - 1 and config.amplitude_check:
                X1h = _images(f, x0, 0.5 * D, h, 0.5 * scale, norm)
                Ah = np.linalg.solve(W.T @ (0.5 * D), W.T @ X1h)
                amp_change = np.abs(_eigs_matched(Ah, pred) - levels[j])
            timings[f"step {h:g}"] = time.perf_counter() - t1
            logger.info("measured the one-period map at step %d/%d (h = %g s) in %.1f s", j + 1, len(config.steps),
                        h, timings[f"step {h:g}"])
    except _Diverged as exc:
        diverged, at, reason = True, exc.at, exc.reason
        logger.warning("multiplier measurement diverged: %s", reason)
    L = np.array(levels) if levels else np.empty((0, k), dtype=complex)
    if diverged or not levels:
        measured = np.empty(0, dtype=complex)
        step_err = amp_err = errors = obs = np.full(k, math.nan)
        step_ok = False
        conv = np.zeros(k, dtype=bool)
        galerkin = np.full(k, math.nan + 0j)
    else:
        step_err, obs, conv, measured = _step_error(L, STEP_FLOOR * float(np.max(np.abs(pred))))
        amp_err = np.where(np.isfinite(amp_change), 4.0 / 3.0 * amp_change, 0.0)
        # a bar that is not small against the multiplier is no measurement of it (e.g. two levels
        # far apart, or a result that moves with the amplitude): not converged, whatever the
        # number of levels
        conv = conv & (np.nan_to_num(step_err, nan=0.0) + amp_err
                       <= MEASURED_FRACTION * np.maximum(np.abs(measured), np.abs(pred)))
        step_ok = bool(np.all(conv))
        errors = np.nan_to_num(step_err, nan=0.0) + amp_err + prediction.errors
    amp = {
        "amplitude": config.amplitude,
        "half": 0.5 * config.amplitude,
        "step": config.steps[-1],
        "change": amp_change,
        # unchanged within the other error sources of the measurement (step) and the prediction
        "passed": bool(config.amplitude_check and not diverged and levels
                       and np.all(amp_change <= np.nan_to_num(step_err, nan=0.0) + prediction.errors + 1e-15)),
    }
    alts = []
    for alt in alternatives:
        if measured.size:
            cand = alt.multipliers
            matched = _eigs_matched(np.diag(cand), measured) if cand.size >= k else np.full(k, math.nan + 0j)
            dist = float(np.max(np.abs(matched - measured)))
            cons = bool(np.all(np.abs(matched - measured) <= errors - prediction.errors + np.resize(alt.errors, k)))
        else:
            matched, dist, cons = alt.multipliers[:k], math.nan, False
        alts.append(Alternative(alt.name, matched, dist, cons))
    # a verdict needs a converged measurement: no agreement claimed on a bar that is not an error estimate
    within = (np.abs(measured - pred) <= errors) & conv if measured.size else np.zeros(k, dtype=bool)
    top = np.abs(pred) >= (1.0 - 1e-9) * float(np.max(np.abs(pred)))
    agrees_dominant = bool(measured.size and not diverged and np.all(within[top]))
    agrees_all = bool(measured.size and not diverged and np.all(within))
    # the verdict covers the multipliers the measurement resolves (see MultiplierValidation.resolved);
    # the dominant one must be among them, the others are listed as unresolved, never dropped silently
    agrees = bool(agrees_dominant and np.all(within[conv]))
    timings["measurement"] = time.perf_counter() - tic
    info.setdefault("period", period)
    info["timings"] = {**info.get("timings", {}), **timings}
    return MultiplierValidation(
        prediction=prediction, measured=measured, levels=L, galerkin=galerkin, step_error=step_err,
        amplitude_error=amp_err, errors=errors, observed_ratio=obs, step_converged=step_ok,
        amplitude_check=amp, alternatives=tuple(alts), diverged=diverged, diverged_at=at, reason=reason,
        agrees=agrees, growth=None, info=info, config=config, converged=conv, agrees_dominant=agrees_dominant,
        agrees_all=agrees_all,
    )


def measure_growth(
    period_map: Callable[[np.ndarray, float, float], np.ndarray],
    x0: np.ndarray,
    direction: np.ndarray,
    norm: EnergyNorm,
    *,
    periods: int,
    period: float,
    step: float,
    amplitude: float = DEFAULT_AMPLITUDE,
    predicted: float = math.nan,
) -> GrowthResult:
    """Follow ``x0 +- d`` and ``x0`` for ``periods`` periods; per-period growth and linear range.

    ``period_map(x, t0, h)`` integrates one period from time ``t0``.  See
    the module docstring (uncontrolled loops).  Never raises for a diverging
    run.
    """
    scale = amplitude * math.sqrt(norm.hub_mass)
    d = np.asarray(direction, dtype=float)
    d = d / norm.norm(d) * scale
    xs = [x0 + d, x0 - d, np.asarray(x0, dtype=float).copy()]
    norms = [scale]
    nonlin: list = []
    diverged, at, reason = False, None, ""
    for kk in range(periods):
        t0 = kk * period
        logger.info("growth run: period %d/%d", kk + 1, periods)
        new = []
        for name, x in zip(("perturbed +", "perturbed -", "reference"), xs):
            try:
                xe = period_map(x, t0, step)
            except Exception as exc:  # solver failure -> reported
                diverged, at, reason = True, t0, f"{name} run failed in period {kk} ([{t0:.4g}, {t0 + period:.4g}] s): {exc}"
                break
            if not np.all(np.isfinite(xe)):
                diverged, at, reason = True, t0 + period, f"{name} run: non-finite state at t = {t0 + period:.4g} s"
                break
            new.append(xe)
        if diverged:
            break
        xs = new
        diff = 0.5 * (xs[0] - xs[1])
        nd = norm.norm(diff)
        if nd > DIVERGENCE_FACTOR * scale:
            diverged, at = True, t0 + period
            reason = f"perturbation grew to {nd / scale:.3g} x its start by t = {at:.4g} s"
            norms.append(nd)
            nonlin.append(norm.norm(xs[0] + xs[1] - 2 * xs[2]) / max(2 * nd, 1e-300))
            break
        norms.append(nd)
        nonlin.append(norm.norm(xs[0] + xs[1] - 2 * xs[2]) / max(2 * nd, 1e-300))
    norms_a = np.array(norms)
    ratios = norms_a[1:] / norms_a[:-1]
    nl = np.array(nonlin)
    outside = np.nonzero(nl > LINEAR_RANGE_TOLERANCE)[0]
    lin_periods = int(outside[0]) if outside.size else int(nl.size)
    left = float((outside[0] + 1) * period) if outside.size else None
    inside = ratios[:lin_periods]
    growth = float(np.exp(np.mean(np.log(inside)))) if inside.size else math.nan
    return GrowthResult(norms=norms_a, ratios=ratios, nonlinearity=nl, linear_periods=lin_periods,
                        linear_range_left_at=left, measured_growth=growth, predicted=float(predicted),
                        diverged=diverged, diverged_at=at, reason=reason)


# --------------------------------------------------------------------------- the refined prediction
#: A mode is compared only if generalised-alpha (trapezoidal, rho_inf = 1) resolves it at the finest
#: step: its phase error over one period, ``(omega h)^2 omega T / 12`` (relative frequency error
#: ``(omega h)^2 / 12`` of the trapezoidal rule), below this (rad).  E.g. the first bending mode
#: (90 Hz) at T = 1 s, h = 2.5e-4 s: 0.92 rad -> not compared; the hub mode (0.4 Hz): 1e-7 rad.
RESOLUTION_PHASE = 0.1


#: The prediction's propagator steps are doubled until the compared multipliers change by less
#: than this (relative to the largest compared modulus) or :data:`PREDICTION_MAX_DOUBLINGS` is reached.
PREDICTION_TOLERANCE = 1e-6
PREDICTION_MAX_DOUBLINGS = 5


def _refined_prediction(name: str, res: Any, lin: Any, labels_sorted: Sequence[str], k: int,
                        allowed: Optional[Sequence[str]], frequencies: Optional[Sequence[float]] = None,
                        h_min: float = 0.0, frame: str = "model", start_steps: Optional[int] = None) -> Prediction:
    """Prediction from the linearisation's monodromy with a converged propagator.

    The exponential-midpoint product of ``res`` (``N`` steps) is refined by step doubling
    (``2N, 4N, ...``) until the compared multipliers change by less than
    :data:`PREDICTION_TOLERANCE`; the last change is the prediction's error estimate (a bound
    on the error of the finer value for a propagator converging at least linearly); from the
    third level on, the error is the grid convergence index of the finest level with the
    observed ratio of the last two changes (capped at 4, the formal second order; safety
    :data:`GCI_SAFETY`), at least two doublings are made.  Why the GCI: on the model-file
    single link (2 pi, 4 elements) the hub multiplier at 512 / 1024 / 2048 / 4096 steps is
    0.29981183 / 203 / 214 / 218 (ratio 1.8, 2.75): the plain last change (2.0e-7 at 1024)
    under-reads the error (the measurement, stable to 1e-8 from T/4096 to T/16384, gives
    0.29981227).  ``frame="modal"`` (model files): the products run in the frozen-modal frame
    of :func:`stability.modal.modal_floquet` (same multipliers; there the midpoint product is
    in its asymptotic range after a few dozen steps instead of thousands), starting from
    ``start_steps``.  Why refine at all:
    measured at Omega = 8 pi, Table 3 gains, 2 elements, the dominant multiplier at
    512 / 1024 / 2048 / 4096 / 8192 steps is 0.3947036 / 0.3946826 / 0.3946488 / 0.3946468 /
    0.3946463: the default 512 steps are 5.7e-5 off, more than the nonlinear measurement's
    error bar, which detected it.
    """
    mu_sorted = np.asarray(res.multipliers)
    T = float(lin.period)

    def labelled(monodromy: np.ndarray) -> list:
        out = []
        for z in np.linalg.eigvals(np.asarray(monodromy)):
            i = int(np.argmin(np.abs(mu_sorted - z)))
            lab = labels_sorted[i]
            if frequencies is not None and h_min > 0:
                w = 2 * math.pi * float(frequencies[i])
                if (w * h_min) ** 2 * w * T / 12.0 > RESOLUTION_PHASE:
                    lab += " (unresolved)"
            out.append(lab)
        return out

    from stability.engines import floquet

    def propagate(steps: int) -> Any:  # the exponential midpoint product, in the frozen-modal frame or the model's
        return floquet(lin, method="modal" if frame == "modal" else "magnus", order=2, n_steps=steps,
                       error_estimate=False, accuracy="moduli").detail
    if start_steps is not None:
        n = int(start_steps)
        previous = np.asarray(propagate(n).monodromy)
    else:
        previous = np.asarray(res.monodromy)
        n = int(res.n_steps)
    pred = None
    last = None  # (multipliers, differences) of the previous doubling
    errors = None
    for _ in range(PREDICTION_MAX_DOUBLINGS):
        n *= 2
        try:
            fine = propagate(n)
        except (ArithmeticError, MemoryError, ValueError, RuntimeError) as exc:  # e.g. the engine's work-array limit
            if pred is None:
                raise
            logger.warning("%s: propagator refinement stopped at %d steps (%s)", name, n // 2, exc)
            n //= 2
            break
        pred = prediction_from_monodromy(name, fine.monodromy, k=k, labels=labelled(fine.monodromy),
                                         allowed=allowed, refined=previous)
        d1 = pred.errors
        if last is None:
            errors = d1.copy()  # two levels: the change itself (order unknown)
        else:
            d0 = np.array([last[1][int(np.argmin(np.abs(last[0] - z)))] for z in pred.multipliers])
            errors = np.empty_like(d1)
            for i in range(d1.size):
                # GCI of the finer level with the observed ratio capped at 4 (exponential midpoint:
                # second order); a ratio below 1.1 is no convergence, and a vanished finest change shows
                # no order: ten times the change (never an error of exactly 0)
                errors[i] = _gci_bar(d0[i], d1[i], abs(pred.multipliers[i]))[0]
        pred = replace(pred, errors=errors)
        if last is not None and float(np.max(errors)) <= PREDICTION_TOLERANCE * float(np.max(np.abs(pred.multipliers))):
            break
        last = (pred.multipliers, d1)
        previous = np.asarray(fine.monodromy)
    logger.info("%s: propagator refined to %d steps, error estimate %s", name, n, pred.errors)
    return replace(pred, name=name, info={"propagator_steps": n})


# --------------------------------------------------------------------------- model files (generic path)
#: Orbit samples of the model-file path.  Why 32 and not 16: the nonlinear runs take their
#: feed-forward torque by trigonometric interpolation of the orbit samples; with 16 the closed
#: loop runs about a slightly different orbit.  Measured on the 4-element single link at 6 pi
#: (Table 3 gains): the hub multiplier converged under step refinement to 0.2968932 with 16
#: samples, 0.2968809 with 32, against the prediction 0.2968808 (the same for 16 and 32: the
#: linearisation is converged in the samples, the interpolated torque is not).
MODEL_SAMPLES = 32
#: First propagator level of the model-file prediction (frozen-modal frame, doubled from here).
MODAL_START_STEPS = 64
#: Newton tolerance of the model-file runs, on the Newton *increment* (Exudyn's
#: ``residualMode = 1``, relative and absolute tolerance equal, as Exudyn asks).  Why not the
#: residual (Exudyn's default): its round-off floor grows as the step shrinks (index-3
#: constraints, stiff ANCF axial terms) -- on the 4-element single link at 2 pi a relative 1e-10
#: is unreachable from h = T/512 on, and with ``adaptiveStep`` (Exudyn's default) the solver
#: then silently cut the step (3245 instead of 512 steps in one period): the finest level
#: jumped from 0.29981 to 0.3458, measurements that did not converge.  A
#: looser residual tolerance (1e-8) runs but stops the + and - runs after different numbers of
#: iterations, so their Newton errors do not cancel in the central difference: the hub
#: multiplier moved by 2e-6 between tolerances 1e-8 and 1e-9 (amplitude 1e-3), and the
#: Kapitza pendulum's finest level was 5e-6 (a = 1e-2) to 1.5e-5 (a = 1e-3) off Mathieu.  The
#: increment test converges to round-off consistently: pendulum 1e-7 (a = 1e-2) and 3e-7
#: (a = 1e-3) from Mathieu, h^2 ratio 4.0; the link's levels at T/1024 ... T/4096 0.29981238,
#: 228, 227.  A step that still fails is reported (``adaptiveStep`` off), never cut.
MODEL_NEWTON_TOLERANCE = 1e-10
#: The coarsest default step makes the spurious multiplier of every strongly damped mode below
#: this (see :func:`suggested_step`; 6 pi data there: 0.17 left a level error of 4e-5, 2e-3 one
#: of ~2e-6).
SPURIOUS_MULTIPLIER = 1e-2
#: Largest ``T / h`` :func:`suggested_step` proposes.
MAX_STEPS_PER_PERIOD = 8192
#: Newton on the position constraints of a perturbed initial state stops below this times
#: ``1 + max |q|`` (round-off of coordinates of order 1).
CONSTRAINT_TOLERANCE = 1e-14


def suggested_step(lin: Any, period: float, spectral_radius: float = 1.0, *, minimum_steps: int = 128) -> float:
    """Coarsest default step ``T / n`` (``n`` a power of two >= ``minimum_steps``) for a closed loop.

    Why: generalised-alpha at ``rho_inf = 1`` is the trapezoidal rule, A-stable but not L-stable:
    a mode ``lambda`` that the loop damps strongly has the discrete one-period multiplier
    ``|g(lambda h)|^(T/h)``, ``g(z) = (1 + z/2) / (1 - z/2)``, instead of ``exp(Re lambda T) ~ 0``.
    For the hub rate under PD (``lambda ~ -kd / J1``, -2.3e5 1/s at Omega = 2 pi with the
    Table 3 gains) that is ``~exp(-4 T / (|lambda| h^2))``; for a PD-damped bending mode that the
    step does not resolve (``omega h >> 1``) ``~exp(Re lambda T / (1 + (omega h / 2)^2))``: up to
    0.6-0.9 at ``h = T/512``.  Such spurious multipliers, excited by whatever part of the
    perturbation the prediction's vectors get wrong, make the step levels of the compared
    multipliers wander instead of converging.  Measured on the 4-element single link through the
    model file (rho_inf = 1, hub multiplier): 2 pi, T/256 ... T/2048: 0.2998107, 0.2998129,
    0.2998122, 0.2998123; 6 pi, T/512 ... T/4096: 0.2972362, 0.2969367, 0.2968963, 0.2968939
    (spurious multiplier of the highest bending mode 0.64, 0.17, 2e-3, 5e-8).
    The rule: the smallest ``n`` with ``| |g|^n - exp(Re lambda T) | <=``
    :data:`SPURIOUS_MULTIPLIER` for every eigenvalue of the frozen first-order matrix at ``t = 0``
    whose own multiplier ``exp(Re lambda T)`` is below 1/2 (lightly damped modes keep ``|g| ~ 1``
    as their true multiplier does, and sit near the unit circle, away from compared ones); at most
    :data:`MAX_STEPS_PER_PERIOD`.  For ``rho_inf < 1``, ``|g|`` is replaced by ``min(|g|, rho_inf)``
    where ``|lambda h| > 2`` (a heuristic: the high-frequency limit of generalised-alpha; with
    rho_inf = 0.95 the 6 pi levels converge as ``h^2`` from T/256 on); the step-refinement error
    bar stays the guard.
    """
    M, C, K = (np.asarray(a[0], dtype=float) for a in (lin.M, lin.C, lin.K))
    r = M.shape[0]
    A = np.zeros((2 * r, 2 * r))
    A[:r, r:] = np.eye(r)
    A[r:, :r] = -np.linalg.solve(M, K)
    A[r:, r:] = -np.linalg.solve(M, C)
    lam = np.linalg.eigvals(A)
    damped = lam[np.exp(np.minimum(lam.real * period, 0.0)) < 0.5]
    n = int(minimum_steps)
    while n < MAX_STEPS_PER_PERIOD:
        z = damped * (period / n)
        g = np.abs((1 + z / 2) / (1 - z / 2))
        g = np.where(np.abs(z) > 2.0, np.minimum(g, float(spectral_radius)), g)
        if np.all(np.abs(g**n - np.exp(damped.real * period)) <= SPURIOUS_MULTIPLIER):
            break
        n *= 2
    return period / n


def _consistent_state(system: Any, q: np.ndarray, v: np.ndarray, t: float,
                      period: float) -> tuple[np.ndarray, np.ndarray]:
    """``(q, v)`` projected onto ``C(q, t) = 0`` and ``C_q v + C_t = 0`` (minimal-norm corrections).

    Why: the perturbed state ``q0 + N0 dz`` violates the position constraints at ``O(|dz|^2)``
    and the orbit's spectral rate ``q0'`` the velocity constraints (6e-5 on the 4-element single
    link with 16 samples); Exudyn's index-3 generalised-alpha then repairs them in the first
    step with an acceleration / multiplier jump that ``rho_inf = 1`` never damps.  Measured at
    Omega = 2 pi, h = T/512: the hub multiplier moved by 1.2e-6 between Newton tolerances 1e-8
    and 1e-9 without the projection, by < 1e-8 with it.  The correction is second order in
    ``dz`` (the first-order part ``N0 dz`` is tangent), so the linear map is unchanged.
    ``C_t`` by Richardson-extrapolated central differences in ``t`` (zero for scleronomic
    constraints; difference step ``1e-3 T``: truncation ``~(2 pi 1e-3)^4``, round-off ``eps / (1e-3 T)``).
    """
    if not system.m:
        return q, v
    q = np.array(q, dtype=float)
    tol = CONSTRAINT_TOLERANCE * (1.0 + float(np.max(np.abs(q))))
    for _ in range(20):
        c = system.constraints(q, t)
        if float(np.max(np.abs(c))) <= tol:
            break
        J = system.constraint_jacobian(q, t)
        q = q - J.T @ np.linalg.lstsq(J @ J.T, c, rcond=None)[0]
    else:
        raise RuntimeError(f"the perturbed initial state cannot be put on the constraints "
                           f"(residual {float(np.max(np.abs(c))):.3g})")
    J = system.constraint_jacobian(q, t)
    e = 1e-3 * float(period)

    def ct(eps: float) -> np.ndarray:
        return (system.constraints(q, t + eps) - system.constraints(q, t - eps)) / (2 * eps)

    c_t = (4.0 * ct(0.5 * e) - ct(e)) / 3.0
    v = np.asarray(v, dtype=float)
    v = v - J.T @ np.linalg.lstsq(J @ J.T, J @ v + c_t, rcond=None)[0]
    return q, v


def _closed_loop_built(definition: Any, omega: float, orbit: Any, kp: np.ndarray, kd: np.ndarray) -> Any:
    """The model with its drives released and driven by feed-forward + PD (the model-file contract).

    Per drive ``j`` with markers ``(m0, m1)`` and driven coordinate ``u = q[m1] - q[m0]``:
    a ``CoordinateSpringDamper`` with ``stiffness = kp_j``, ``damping = kd_j`` whose force
    user function shifts its offsets to the motion (``kp (u - r) + kd (u' - r')``; Exudyn's
    Jacobian uses ``stiffness``/``damping``, so Newton sees the exact PD derivative), and
    the feed-forward torque ``tau_j(t)`` of the orbit as ``LoadCoordinate`` ``+tau`` on
    ``m1`` and ``-tau`` on ``m0`` (``M q'' = f + B tau``, ``B = e_m1 - e_m0``).
    """
    from exudyn.itemInterface import CoordinateSpringDamper, LoadCoordinate

    from mbs_models.model_file import build_model

    built = build_model(definition, omega, prescribe_drives=False)
    mbs = built.mbs
    for j, (d, (i0, i1)) in enumerate(zip(built.drives, built.drive_indices)):
        motion = d.motion

        def pd(mbs_, t, item, u, v, k, dmp, off, _motion=motion):  # noqa: ARG001  (Exudyn signature)
            r, r_t, _ = _motion(t)
            return k * (u - float(r)) + dmp * (v - float(r_t))

        mbs.AddObject(CoordinateSpringDamper(markerNumbers=list(d.markers), stiffness=float(kp[j]),
                                             damping=float(kd[j]), springForceUserFunction=pd,
                                             name=f"PD {d.name}"))
        for marker, idx, sign in ((d.markers[1], i1, 1.0), (d.markers[0], i0, -1.0)):
            if idx < 0:
                continue  # ground coordinate: no equation

            def load(mbs_, t, value, _j=j, _s=sign):  # noqa: ARG001
                return _s * float(orbit.torque(t)[_j])

            mbs.AddLoad(LoadCoordinate(markerNumber=int(marker), load=0.0, loadUserFunction=load))
    mbs.Assemble()
    return built


def _run_settings(t0: float, t1: float, h: float, spectral_radius: float = 1.0) -> Any:
    import exudyn as exu

    s = exu.SimulationSettings()
    s.timeIntegration.startTime = float(t0)
    s.timeIntegration.endTime = float(t1)
    s.timeIntegration.numberOfSteps = max(1, int(round((t1 - t0) / h)))
    s.timeIntegration.generalizedAlpha.spectralRadius = float(spectral_radius)
    s.timeIntegration.verboseMode = 0
    s.timeIntegration.automaticStepSize = False
    s.timeIntegration.adaptiveStep = False  # a failing step is reported, never silently cut
    s.timeIntegration.newton.residualMode = 1  # increment test, see MODEL_NEWTON_TOLERANCE
    s.timeIntegration.newton.relativeTolerance = MODEL_NEWTON_TOLERANCE
    s.timeIntegration.newton.absoluteTolerance = MODEL_NEWTON_TOLERANCE
    s.timeIntegration.newton.useModifiedNewton = False
    s.solution.file.write = False
    s.solution.file.writeInitialValues = False
    s.show.statistics = False
    s.show.computationTime = False
    s.linearSolver.solverType = exu.LinearSolverType.EigenDense
    return s


def refuse_lie_group_nodes(built: Any) -> None:
    """Refuse (one line) to validate a model with rotation-vector (Lie group) nodes.

    Why: Exudyn's implicit generalised-alpha runs of such a model do not converge in the step for the
    perturbed states.  Measured on ``tests/models/swinging_rod.py`` with ``node="RV"`` (joint-held rod,
    Omega = 5): the one-period map measured from perturbed runs has the multipliers
    (-5.5, -0.85, 0.13, 2.8) at h = T/256 and (0.06 +- 1.10i, 1.5, 5.2e3) at h = T/1024, and the run fails at
    T/4096, while the same rod with a ``NodeRigidBodyEP`` node converges to the prediction and the unperturbed
    rotation-vector run returns to the orbit at second order in h.

    Raises
    ------
    mbs_models.model_file.ModelFileError
    """
    from linearize.exudyn_system import lie_group_nodes
    from mbs_models.model_file import ModelFileError

    if lie_group_nodes(built.mbs):
        raise ModelFileError(
            f"model {built.definition.name}: validate does not run models with a NodeRigidBodyRotVecLG (Exudyn's "
            f"implicit integration of its perturbed runs does not converge in the step); floquet, tune and the study "
            f"do; to validate, give the body a NodeRigidBodyEP or a NodeRigidBodyRxyz node")


def validate_model_multipliers(
    model: Any,
    omega: float,
    kp: "float | Sequence[float]" = 0.0,
    kd: "float | Sequence[float]" = 0.0,
    *,
    samples: int = MODEL_SAMPLES,
    config: MultiplierCheckConfig = MultiplierCheckConfig(step=None, amplitude=None),
    predicted_gains: Optional[tuple] = None,
    alternatives: Sequence[Prediction] = (),
    quiet: bool = True,
    **options: Any,
) -> MultiplierValidation:
    """Measure the multipliers of a model file's nonlinear closed loop (generic path).

    The prediction is :func:`linearize.analysis.analyze` (orbit, constraint-correct
    linearisation in independent coordinates ``z``, ``dq = N(t) z``).  A
    perturbation ``[dz, dz']`` of the orbit state at ``t = 0`` is applied in Exudyn's
    coordinates as ``q = q0 + N0 dz``, ``q' = q0' + N0 dz' + N0' dz``, projected onto the
    position and velocity constraints (:func:`_consistent_state`; a second-order correction),
    and read back at ``T`` with the pseudo-inverse of ``N0`` (``N`` is T-periodic).
    Exudyn runs with Newton tolerance :data:`MODEL_NEWTON_TOLERANCE` and ``adaptiveStep``
    off (a failing step is a reported failure, never a silently smaller step); the default
    coarsest step is :func:`suggested_step`, the default amplitude :data:`MODEL_AMPLITUDE`.

    Parameters
    ----------
    model : str, path, ModelDefinition or callable
        As for :func:`linearize.analysis.analyze`.
    omega : float
    kp, kd : float or sequence
        PD gains per drive (or one for all).
    samples : int
        Orbit / linearisation samples (default :data:`MODEL_SAMPLES`; the nonlinear runs
        get their feed-forward torque by trigonometric interpolation of these samples).
    config : MultiplierCheckConfig
    predicted_gains : (kp, kd), optional
        Gains of the prediction under test (default: the simulated ones).
    alternatives : sequence of Prediction
        Other predictions to report distances to (e.g. :func:`prediction_from_multipliers` of a
        reduced model); each is cut to the number of compared multipliers.
    quiet : bool
    **options
        Keyword options of the model's ``build``.

    Returns
    -------
    MultiplierValidation
    """
    import exudyn as exu

    from linearize.analysis import analyze
    from linearize.exudyn_system import ExudynSystem, from_exudyn_velocity, lie_group_nodes, to_exudyn_velocity
    from mbs_models.model_file import build_model, resolve_model
    from mbs_models.console import exudyn_console

    tic = time.perf_counter()
    omega = float(omega)
    if not (math.isfinite(omega) and omega > 0):
        raise ValueError(f"omega must be finite and > 0, got {omega!r}")
    T = 2 * math.pi / omega
    if config.step is not None and config.step >= T:
        raise ValueError(f"step must be smaller than the period T = {T:.6g} s, got {config.step!r}")
    definition = resolve_model(model, **options)
    timings: dict = {}
    with exudyn_console(quiet):
        refuse_lie_group_nodes(build_model(definition, omega))
        ex = analyze(definition, omega, kp=kp, kd=kd, samples=samples)
        timings["prediction"] = time.perf_counter() - tic
        logger.info("prediction (orbit, linearisation, multipliers) in %.1f s", timings["prediction"])
        lin, orbit = ex.linearization, ex.orbit
        if config.amplitude is None:
            config = replace(config, amplitude=MODEL_AMPLITUDE)
        if config.step is None:
            config = replace(config, step=suggested_step(lin, T, config.spectral_radius))
        if config.step >= T:
            raise ValueError(f"step must be smaller than the period T = {T:.6g} s, got {config.step!r}")
        d = lin.drives
        kp_a = np.resize(np.asarray(lin.kp, dtype=float), d) if lin.B is not None else np.zeros(0)
        kd_a = np.resize(np.asarray(lin.kd, dtype=float), d) if lin.B is not None else np.zeros(0)
        tested = ex
        name = "linearisation about the periodic orbit"
        if predicted_gains is not None:
            tested = analyze(definition, omega, kp=predicted_gains[0], kd=predicted_gains[1], samples=samples,
                             orbit=orbit)
            name += f" with kp = {predicted_gains[0]}, kd = {predicted_gains[1]}"
        res = tested.floquet
        prediction = _refined_prediction(name, res, tested.linearization, [m.mode for m in tested.modes],
                                         config.compare, None,
                                         [float(m.frequency_hz or 0.0) for m in tested.modes],
                                         config.steps[-1], frame="modal", start_steps=MODAL_START_STEPS)
        r = lin.size
        N0, N0t = lin.basis[0], lin.basis_t[0]
        N0p = np.linalg.pinv(N0)
        q0, v0 = orbit.q[0].copy(), orbit.q_t[0].copy()
        # the orbit map q0(t + T) = g(q0(t)): whole turns of angles, sign flips S of the Euler parameters of a
        # turning body (the basis is S-periodic, N(T) = S N(0)); S = S^-1
        S = np.asarray(orbit.signs, dtype=float)
        qT0, _ = orbit.map_state(q0, v0)
        norm = energy_norm(lin.M[0], lin.K[0])
        if d:
            # the hub-mass scale of the amplitude: the first driven coordinate's mass
            norm = EnergyNorm(norm.Lk, norm.Lm, float(lin.B[0][:, 0] @ np.linalg.solve(lin.M[0], lin.B[0][:, 0])) ** -1)
        built = _closed_loop_built(definition, omega, orbit, kp_a, kd_a)
        mbs, sd = built.mbs, built.mbs.systemData
        ini = exu.ConfigurationType.Initial
        # constraint evaluations on a separate build (the closed loop's solver stays untouched)
        constraints = ExudynSystem(build_model(definition, omega))
        lie = lie_group_nodes(mbs)  # rotation-vector nodes: Exudyn's velocities are angular velocities

        def start(x: np.ndarray, t0: float = 0.0) -> None:
            dz, dzt = x[:r], x[r:]
            q_ref, v_ref = orbit.map_state(q0, v0, round(t0 / T))  # the orbit at t0 = j T
            Sj = S ** round(t0 / T)
            q, v = _consistent_state(constraints, q_ref + Sj * (N0 @ dz), v_ref + Sj * (N0 @ dzt + N0t @ dz), t0, T)
            sd.SetODE2Coordinates(q, configuration=ini)
            sd.SetODE2Coordinates_t(to_exudyn_velocity(lie, q, v), configuration=ini)

        def run(x: np.ndarray, h: float) -> np.ndarray:
            start(x)
            ok = mbs.SolveDynamic(_run_settings(0.0, T, h, config.spectral_radius))
            if ok is False:
                raise RuntimeError("Exudyn time integration did not succeed")
            qT = np.array(sd.GetODE2Coordinates())
            vT = from_exudyn_velocity(lie, qT, np.array(sd.GetODE2Coordinates_t()))
            ez = N0p @ (S * (qT - qT0))
            ezt = N0p @ (S * vT - v0 - N0t @ ez)
            return np.concatenate([ez, ezt])

        def factory(h: float):
            return run

        info = {
            "model": definition.name,
            "omega": omega,
            "omega_over_pi": omega / math.pi,
            "period": T,
            "drives": [{"name": n, "kp": float(a), "kd": float(b)} for n, a, b in zip(lin.drive_names, kp_a, kd_a)],
            "kp": kp_a.tolist(),
            "kd": kd_a.tolist(),
            "samples": samples,
            "compare": int(prediction.multipliers.size),
            "amplitude": config.amplitude,
            "orbit_residual": float(orbit.residual),
            "timings": timings,
        }
        k_eff = int(prediction.multipliers.size)
        alts = [replace(a, multipliers=a.multipliers[:k_eff], labels=a.labels[:k_eff], errors=a.errors[:k_eff])
                for a in alternatives]
        result = measure_multipliers(factory, np.zeros(2 * r), prediction, norm, config, alternatives=alts,
                                     info=info, period=T)
        if config.growth_periods > 0:
            t1 = time.perf_counter()

            def pm(x, t0, h):
                start(x, t0)
                if mbs.SolveDynamic(_run_settings(t0, t0 + T, h, config.spectral_radius)) is False:
                    raise RuntimeError("Exudyn time integration did not succeed")
                qT = np.array(sd.GetODE2Coordinates())
                vT = from_exudyn_velocity(lie, qT, np.array(sd.GetODE2Coordinates_t()))
                j = round(t0 / T) + 1
                q_ref, v_ref = orbit.map_state(q0, v0, j)
                Sj = S ** j
                ez = N0p @ (Sj * (qT - q_ref))
                return np.concatenate([ez, N0p @ (Sj * vT - v0 - N0t @ ez)])

            growth = measure_growth(pm, np.zeros(2 * r), prediction.right[:, 0], norm,
                                    periods=config.growth_periods, period=T, step=config.step,
                                    amplitude=config.amplitude, predicted=float(abs(prediction.multipliers[0])))
            result.info["timings"]["growth"] = time.perf_counter() - t1
            result = replace(result, growth=growth)
    result.info["timings"]["total"] = time.perf_counter() - tic
    return result
