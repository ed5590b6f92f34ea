"""Nonlinear closed-loop validation of the predicted Floquet multipliers.

:func:`validate_closed_loop` simulates the free-hub Exudyn model under
feed-forward + PD (:func:`~_link_oracle.exudyn_link.build_link_model`, drive
``"free"``) twice with the same integrator and the same steps:

* the **reference** run from the periodic orbit's state at ``t = 0`` (the
  orbit of :func:`~_link_oracle.link_orbit.find_periodic_orbit`, whose feed-forward
  torque makes it the closed-loop orbit for any gains);
* the **perturbed** run from the same state with the hub velocity raised by
  ``perturbation`` (paper Eqs. 26/35: ``y_1' (0) = 0.25 pi`` rad/s; in the
  hub-frame coordinates this turns the whole undeformed link rigidly, as the
  paper's ``y_1``).

The perturbation is the difference of the two runs (so the integrator's own
error along the orbit cancels), measured per period ``T = 2 pi / Omega``

* stroboscopically: ``s_k = |Delta q_a(k T)|``;
* as an envelope: ``e_k = max |Delta q_a(t)|`` over ``[k T, (k+1) T]``;

and the per-period ratio is fitted by least squares on ``ln s_k`` against
``k`` (``k >= 1``: the first period, in which the kick's fast transients die
out, is left out).  It is compared with the dominant multiplier predicted by
(a) the paper's reduced model (:class:`~mbs_models.reduced.ReducedModel`) and
(b) the Exudyn linearisation along the orbit
(:func:`~_link_oracle.link_floquet.exudyn_floquet`).

Maths
-----
Near the orbit the perturbation obeys ``x((k+1)T) = Phi x(kT)`` with the
monodromy matrix ``Phi``; with a simple, real dominant multiplier ``rho_1``
every fixed component of ``x(kT)`` is eventually ``c rho_1^k``, so
``s_{k+1} / s_k -> |rho_1|`` (the power method; the other multipliers die
out relative to it by ``|rho_2 / rho_1|^k``).

Linear range and divergence
---------------------------
Unstable loops (``kp = kd = 0``: ``rho_1 = 13.6`` at ``Omega = 2 pi``)
amplify every error, including the reference run's own drift from the
orbit (integrator error, ~6e-4 rad after one period at ``h = 1e-3``).  The
motion is called *outside the linear range* from the first sample at which
the perturbation ``|Delta q_a|`` or the reference drift
``|q_a - q_a^R|`` exceeds :data:`LINEAR_RANGE_ANGLE`; only complete periods
before that enter the fit, and :attr:`ValidationResult.linear_range_left_at`
says when it happened.  A run is *diverged* when Exudyn's solver fails
(:class:`~_link_oracle.exudyn_link.ExudynSolverError`), a state is not finite,
the hub error exceeds :data:`DIVERGENCE_ANGLE` or a beam node leaves the
disc of radius :data:`DIVERGENCE_STRETCH` ``* l`` (an absurd axial strain):
the result then says ``diverged=True`` with the time and the reason; the
function does not raise.  Exudyn with fixed steps rarely fails outright: we
measured hub angles of 1e9 rad without a solver error (``h = 0.3`` s), hence
the physical checks.

Why not :func:`stability.response.linear_response` for the linear prediction
---------------------------------------------------------------------------
The linearised Exudyn system has undamped axial modes up to 47 kHz and a hub
eigenvalue near ``-kd/J1 = -5e5`` 1/s; Radau at ``rtol = 1e-6`` needed more
than 90 s for three periods at 4 elements (stopped).  :func:`linear_prediction`
propagates with the exponential midpoint factors
``exp(h P(t_j + h/2))`` of the Floquet engine
(:func:`stability.magnus.magnus_factors`, ``"magnus2"``), computed for one
period and reused every period (``P`` is T-periodic).  Its stroboscopic
samples are exactly ``Phi_expmid^k x0``.

References
----------
.. [1] Dat, D. C., Khang, N. V., Hoang, N. Q., Quyen, N. V., *Stability
   Control of Dynamical Systems Described by Linear Differential Equations
   with Time-Periodic Coefficients*, Eqs. (26), (27), (35), Table 3.
"""
from __future__ import annotations

import contextlib
import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Iterator, Optional

import numpy as np

from _link_oracle.exudyn_link import ExudynSolverError, build_link_model, fundamental_motion
from mbs_models.console import exudyn_console
from mbs_models.parameters import ManipulatorParameters
from stability.serialization import json_ready

__all__ = [
    "AGREEMENT_TOLERANCE",
    "DIVERGENCE_ANGLE",
    "DIVERGENCE_STRETCH",
    "LINEAR_RANGE_ANGLE",
    "NOISE_FLOOR",
    "PAPER_PERTURBATION",
    "LinearPrediction",
    "ValidationResult",
    "linear_prediction",
    "validate_closed_loop",
]

logger = logging.getLogger(__name__)

#: Hub-velocity perturbation of the paper's transients, rad/s (Eqs. 26/35:
#: ``x(0) = [0, 0, 0.25 pi, 0]``).
PAPER_PERTURBATION = 0.25 * math.pi
#: Hub-angle error (perturbation or reference drift, rad) beyond which the
#: motion is called outside the linear range.  Measured at Omega = 2 pi,
#: uncontrolled, 4 elements: per-period growth 13.74 (0.7 % above the
#: linearisation's 13.64) while both stay below 0.008 rad, 14.07 (3 %) once
#: the reference drift reaches 0.11 rad.
LINEAR_RANGE_ANGLE = 0.05
#: Hub-angle error (rad, ~16 revolutions) beyond which a run is diverged.
DIVERGENCE_ANGLE = 100.0
#: A beam node farther than this many link lengths from O: diverged
#: (50 % axial strain; the aluminium link yields at ~0.3 %).
DIVERGENCE_STRETCH = 1.5
#: Stroboscopic samples below this (rad) are not used in the fit: the
#: difference of two runs carries the Newton tolerance (1e-8 relative on
#: hub angles of order 1-3 rad) and round-off.
NOISE_FLOOR = 1e-9
#: Relative deviation of the measured ratio from the Exudyn prediction
#: accepted as agreement (within 10 %).
AGREEMENT_TOLERANCE = 0.10
#: Exponential-midpoint steps per period of :func:`linear_prediction`.
DEFAULT_PREDICTION_STEPS = 256


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class ValidationResult:
    """Nonlinear closed-loop run against the predicted dominant multipliers.

    Attributes
    ----------
    omega, kp, kd : float
        Frequency of the fundamental motion (rad/s) and PD gains.
    elements : int
        ANCF elements.
    periods : int
        Periods requested.
    periods_completed : int
        Periods simulated before the end or a divergence.
    perturbation : float
        Hub-velocity perturbation at ``t = 0`` (rad/s).
    step : float
        Generalised-alpha step (s).
    period : float
        ``T = 2 pi / omega``.
    predicted_multiplier_reduced : float
        Spectral radius of the reduced model (paper constants).
    predicted_multiplier_exudyn : float
        ``|rho|`` of the dominant multiplier of the Exudyn linearisation
        (paper's modes, see :class:`~_link_oracle.link_floquet.ExudynFloquetResult`).
    predicted_mode_exudyn : str
        Its mode label (``"hub"``, ...).
    spectral_radius_exudyn : float
        Max over all multipliers of the linearisation (undamped modes included).
    measured_ratio_per_period : float
        Least-squares per-period ratio of the stroboscopic hub error
        (``s_k``, ``k >= 1``, linear range only); NaN with fewer than two
        usable samples.
    measured_ratio_envelope : float
        The same fitted to the envelope ``e_k`` (``k >= 1``).
    ratios : ndarray
        ``s_{k+1} / s_k`` for ``k = 1 ..``.
    stroboscopic : ndarray, shape (periods_completed + 1,)
        ``|Delta q_a(k T)|`` (rad).
    envelope, tip_envelope : ndarray, shape (periods_completed,)
        ``max |Delta q_a|`` (rad) and ``max |Delta w_tip|`` (m) per period.
    reference_drift : ndarray, shape (periods_completed,)
        ``max |q_a - q_a^R|`` of the reference run per period (rad).
    fit_periods : tuple of int
        Stroboscopic indices ``k`` used by the fit.
    linear_range_left_at : float or None
        First time (s) at which the perturbation or the reference drift
        exceeded ``linear_range_angle``; ``None`` if never.
    linear_range_left_period : int or None
        Period index of that time.
    linear_range_angle : float
    diverged : bool
    diverged_at : float or None
        Time (s) of the first diverged sample, or the start of the period in
        which Exudyn's solver failed.
    reason : str
        Why the run diverged (empty if not).
    relative_error_exudyn, relative_error_reduced : float
        ``measured / predicted - 1``.
    agrees : bool
        ``|relative_error_exudyn| <= AGREEMENT_TOLERANCE``.
    last_ratio : float
        The last per-period ratio in the linear range (the most converged one
        when the other multipliers die out slowly relative to ``rho_1``, e.g.
        uncontrolled at 8 pi: ``rho_1 = 1.88`` against undamped modes on the
        unit circle).
    linear_stroboscopic : ndarray
        ``|y_1(kT)|`` of the linearised Exudyn system from the same initial
        perturbation (:func:`linear_prediction`); empty if not computed.
    linear_ratio_per_period : float
        The same least-squares fit applied to ``linear_stroboscopic`` over
        ``fit_periods``: compares like with like, the initial transient
        included (NaN if not computed).
    times, hub_error, tip_error, drift : ndarray
        Time series of the perturbation (every solver step) and of the
        reference drift.
    timings : dict
        Seconds per stage (``exudyn_floquet``, ``reduced``,
        ``simulation_reference``, ``simulation_perturbed``, ``total``) and
        ``simulated_time`` (s of model time per run).
    exudyn : ExudynFloquetResult
        The linearisation and its Floquet analysis (for plots).
    params : ManipulatorParameters
    """

    omega: float
    kp: float
    kd: float
    elements: int
    periods: int
    periods_completed: int
    perturbation: float
    step: float
    period: float
    predicted_multiplier_reduced: float
    predicted_multiplier_exudyn: float
    predicted_mode_exudyn: str
    spectral_radius_exudyn: float
    measured_ratio_per_period: float
    measured_ratio_envelope: float
    ratios: np.ndarray
    stroboscopic: np.ndarray
    envelope: np.ndarray
    tip_envelope: np.ndarray
    reference_drift: np.ndarray
    fit_periods: tuple
    linear_range_left_at: Optional[float]
    linear_range_left_period: Optional[int]
    linear_range_angle: float
    diverged: bool
    diverged_at: Optional[float]
    reason: str
    relative_error_exudyn: float
    relative_error_reduced: float
    agrees: bool
    last_ratio: float
    linear_stroboscopic: np.ndarray
    linear_ratio_per_period: float
    times: np.ndarray = field(repr=False)
    hub_error: np.ndarray = field(repr=False)
    tip_error: np.ndarray = field(repr=False)
    drift: np.ndarray = field(repr=False)
    timings: dict = field(default_factory=dict)
    exudyn: Any = field(default=None, repr=False)
    params: Optional[ManipulatorParameters] = field(default=None, repr=False)
    prediction: Any = field(default=None, repr=False)

    @property
    def growing(self) -> bool:
        """Whether the perturbation grew (last envelope above the first)."""
        return bool(self.envelope.size >= 2 and self.envelope[-1] > self.envelope[0])

    def to_dict(self) -> dict:
        """JSON-ready dict (NaN -> ``None``); time series are left out."""
        d = {
            "omega": self.omega,
            "omega_over_pi": self.omega / math.pi,
            "kp": self.kp,
            "kd": self.kd,
            "elements": self.elements,
            "periods": self.periods,
            "periods_completed": self.periods_completed,
            "perturbation": self.perturbation,
            "step": self.step,
            "period": self.period,
            "predicted_multiplier_reduced": self.predicted_multiplier_reduced,
            "predicted_multiplier_exudyn": self.predicted_multiplier_exudyn,
            "predicted_mode_exudyn": self.predicted_mode_exudyn,
            "spectral_radius_exudyn": self.spectral_radius_exudyn,
            "measured_ratio_per_period": self.measured_ratio_per_period,
            "measured_ratio_envelope": self.measured_ratio_envelope,
            "relative_error_exudyn": self.relative_error_exudyn,
            "relative_error_reduced": self.relative_error_reduced,
            "agrees": self.agrees,
            "agreement_tolerance": AGREEMENT_TOLERANCE,
            "last_ratio": self.last_ratio,
            "linear_ratio_per_period": self.linear_ratio_per_period,
            "linear_stroboscopic": self.linear_stroboscopic,
            "ratios": self.ratios,
            "stroboscopic": self.stroboscopic,
            "envelope": self.envelope,
            "tip_envelope": self.tip_envelope,
            "reference_drift": self.reference_drift,
            "fit_periods": list(self.fit_periods),
            "growing": self.growing,
            "linear_range_angle": self.linear_range_angle,
            "linear_range_left_at": self.linear_range_left_at,
            "linear_range_left_period": self.linear_range_left_period,
            "diverged": self.diverged,
            "diverged_at": self.diverged_at,
            "reason": self.reason,
            "timings": dict(self.timings),
        }
        return json_ready(d)


# --------------------------------------------------------------------------- helpers
def _check_int(name: str, value: Any, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer, float)) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _check_float(name: str, value: Any, *, positive: bool = False, non_negative: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and v <= 0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    if non_negative and v < 0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return v


def _fit_ratio(values: np.ndarray, indices: np.ndarray) -> float:
    """``exp(slope)`` of the least-squares line through ``(k, ln values)``; NaN with < 2 points."""
    keep = np.isfinite(values) & (values > NOISE_FLOOR)
    k, v = indices[keep], values[keep]
    if k.size < 2:
        return math.nan
    slope = np.polyfit(k.astype(float), np.log(v), 1)[0]
    return float(math.exp(slope))


@dataclass
class _Run:
    """Samples of one simulation, accumulated period by period."""

    times: list = field(default_factory=list)
    hub: list = field(default_factory=list)
    tip: list = field(default_factory=list)
    radius: list = field(default_factory=list)
    wall: float = 0.0

    def extend(self, res: Any, first: bool, N: int) -> None:
        sl = slice(0, None) if first else slice(1, None)  # segment start = previous end
        self.times.append(res.times[sl])
        self.hub.append(res.hub_angle[sl])
        self.tip.append(res.tip_deflection[sl])
        nodes = res.positions[sl, 2:].reshape(res.positions[sl].shape[0], N, 4)[:, :, :2]
        self.radius.append(np.max(np.hypot(nodes[..., 0], nodes[..., 1]), axis=1))
        self.wall += res.wall_time

    def arrays(self) -> tuple[np.ndarray, ...]:
        cat = (lambda a: np.concatenate(a) if a else np.empty(0))
        return cat(self.times), cat(self.hub), cat(self.tip), cat(self.radius)


def _divergence(t: np.ndarray, hub_err: np.ndarray, radius: np.ndarray, length: float) -> tuple[Optional[float], str]:
    """First sample that is non-finite or beyond the divergence limits."""
    bad_finite = ~(np.isfinite(hub_err) & np.isfinite(radius))
    bad_angle = np.abs(np.nan_to_num(hub_err, nan=0.0)) > DIVERGENCE_ANGLE
    bad_stretch = np.nan_to_num(radius, nan=0.0) > DIVERGENCE_STRETCH * length
    bad = bad_finite | bad_angle | bad_stretch
    if not np.any(bad):
        return None, ""
    i = int(np.argmax(bad))
    if bad_finite[i]:
        why = "non-finite state"
    elif bad_angle[i]:
        why = f"hub-angle error {abs(hub_err[i]):.3g} rad > {DIVERGENCE_ANGLE:g} rad"
    else:
        why = f"beam node at {radius[i]:.3g} m from O > {DIVERGENCE_STRETCH:g} l = {DIVERGENCE_STRETCH * length:.3g} m"
    return float(t[i]), why


# --------------------------------------------------------------------------- main entry
def validate_closed_loop(
    params: Optional[ManipulatorParameters] = None,
    omega: float = 2 * math.pi,
    kp: float = 0.0,
    kd: float = 0.0,
    *,
    elements: int = 8,
    periods: int = 5,
    perturbation: float = PAPER_PERTURBATION,
    step: float = 1e-3,
    samples: int = 32,
    linear_range_angle: float = LINEAR_RANGE_ANGLE,
    orbit: Any = None,
    exudyn_result: Any = None,
    quiet: bool = True,
    linear: bool = True,
) -> ValidationResult:
    """Simulate the perturbed nonlinear closed loop and measure its per-period decay.

    Parameters
    ----------
    params : ManipulatorParameters, optional
        Physical data (default: the paper's Table 1).
    omega : float
        Frequency of the fundamental motion (rad/s, > 0).
    kp, kd : float
        PD gains on the hub (>= 0); ``0, 0`` is the uncontrolled loop.
    elements : int
        ANCF elements (>= 1).
    periods : int
        Periods to simulate (>= 1).
    perturbation : float
        Hub-velocity perturbation at ``t = 0`` in rad/s (default the paper's
        ``0.25 pi``, Eqs. 26/35); non-zero.
    step : float
        Generalised-alpha step in s (0 < step < T).
    samples : int
        Orbit / linearisation samples per period.
    linear_range_angle : float
        See :data:`LINEAR_RANGE_ANGLE`.
    orbit : PeriodicOrbit, optional
        Reuse a periodic orbit (same ``omega`` and ``elements``); it does not
        depend on the gains.
    exudyn_result : ExudynFloquetResult, optional
        Reuse an Exudyn Floquet analysis for these ``omega, kp, kd, elements``.
    quiet : bool
        Silence Exudyn's console output during the runs.
    linear : bool
        Also compute the linear prediction (:func:`linear_prediction`, ~0.1 s)
        and its fitted ratio.

    Returns
    -------
    ValidationResult
        Never raises for a diverging or failing simulation (``diverged=True``).

    Raises
    ------
    ValueError
        On invalid arguments (non-positive periods or elements, non-finite
        omega, negative gains, ...).
    _link_oracle.link_orbit.OrbitConvergenceError
        If the periodic orbit cannot be found (there is nothing to validate).

    Examples
    --------
    >>> r = validate_closed_loop(omega=2 * math.pi, kp=37.1617, kd=29.2410,
    ...                          elements=2, periods=3)  # doctest: +SKIP
    >>> round(r.measured_ratio_per_period, 2)  # doctest: +SKIP
    0.3
    """
    t_total = time.perf_counter()
    omega = _check_float("omega", omega, positive=True)
    kp = _check_float("kp", kp, non_negative=True)
    kd = _check_float("kd", kd, non_negative=True)
    elements = _check_int("elements", elements)
    periods = _check_int("periods", periods)
    perturbation = _check_float("perturbation", perturbation)
    if perturbation == 0.0:
        raise ValueError("perturbation must be non-zero")
    linear_range_angle = _check_float("linear_range_angle", linear_range_angle, positive=True)
    T = 2 * math.pi / omega
    step = _check_float("step", step, positive=True)
    if step >= T:
        raise ValueError(f"step must be smaller than the period T = {T:.6g} s, got {step!r}")
    params = ManipulatorParameters() if params is None else params
    if not isinstance(params, ManipulatorParameters):
        raise ValueError(f"params must be ManipulatorParameters, got {type(params).__name__}")

    from _link_oracle.link_floquet import exudyn_floquet
    from mbs_models.reduced import ReducedModel
    from stability import floquet

    timings: dict = {}
    tic = time.perf_counter()
    rho_reduced = float(floquet(ReducedModel(omega=omega, kp=kp, kd=kd, params=params)).spectral_radius)
    timings["reduced"] = time.perf_counter() - tic

    tic = time.perf_counter()
    if exudyn_result is None:
        exudyn_result = exudyn_floquet(
            params, omega=omega, kp=kp, kd=kd, elements=elements, samples=samples, orbit=orbit
        )
    elif (abs(exudyn_result.omega - omega) > 1e-12 * omega or exudyn_result.kp != kp
          or exudyn_result.kd != kd or exudyn_result.elements != elements):
        raise ValueError("exudyn_result was computed for other omega, gains or elements")
    timings["exudyn_floquet"] = time.perf_counter() - tic
    rho_exudyn = float(abs(exudyn_result.dominant_multiplier))
    orb = exudyn_result.orbit

    cfg = replace(orb.config, drive="free", kp=kp, kd=kd, step_size=step)
    model = build_link_model(params, cfg, feedforward=orb.hub_torque)
    motion = fundamental_motion(cfg)
    p0, v0 = orb.positions[0].copy(), orb.velocities[0].copy()
    v1 = v0.copy()
    v1[0] += perturbation

    ref, per = _Run(), _Run()
    state_ref, state_per = (p0, v0), (p0, v1)
    diverged, diverged_at, reason = False, None, ""
    completed = 0
    with exudyn_console(quiet):
        for k in range(periods):
            t0, t1 = k * T, (k + 1) * T
            for name, run, state in (("reference", ref, state_ref), ("perturbed", per, state_per)):
                try:
                    res = model.simulate(state[0], state[1], t1, t_start=t0, record=True)
                except (ExudynSolverError, ValueError) as exc:
                    diverged, diverged_at = True, float(t0)
                    reason = f"{name} run: Exudyn solver failed in [{t0:.4g}, {t1:.4g}] s: {exc}"
                    break
                run.extend(res, k == 0, elements)
                if name == "reference":
                    state_ref = (res.positions[-1], res.velocities[-1])
                else:
                    state_per = (res.positions[-1], res.velocities[-1])
            if diverged:
                break
            # divergence checks on this period's samples
            t_ref, hub_ref, _, _ = ref.arrays()
            for name, run in (("reference", ref), ("perturbed", per)):
                t, hub, _, rad = run.arrays()
                # Exudyn may cut steps when Newton fails (adaptive step), so the
                # grids of the two runs can differ: compare on the run's own grid
                err = hub - np.interp(t, t_ref, hub_ref) if name == "perturbed" else hub - motion(t)[0]
                at, why = _divergence(t, err, rad, params.length)
                if at is not None:
                    diverged, diverged_at, reason = True, at, f"{name} run: {why} at t = {at:.4g} s"
                    break
            if diverged:
                break
            completed = k + 1
    timings["simulation_reference"] = ref.wall
    timings["simulation_perturbed"] = per.wall
    timings["simulated_time"] = completed * T

    t, hub_r, tip_r, _ = ref.arrays()
    t_p, hub_p, tip_p, _ = per.arrays()
    if t_p.size != t.size or not np.allclose(t_p, t, rtol=0.0, atol=1e-9 * T):
        # different step sequences (Newton step cuts): perturbed run onto the reference grid
        n_common = t <= (t_p[-1] if t_p.size else -1.0)
        t, hub_r, tip_r = t[n_common], hub_r[n_common], tip_r[n_common]
        hub_p, tip_p = np.interp(t, t_p, hub_p), np.interp(t, t_p, tip_p)
    if completed < periods and t.size:  # keep only the completed periods
        keep = t <= completed * T + 1e-9 * T
        t, hub_r, tip_r, hub_p, tip_p = t[keep], hub_r[keep], tip_r[keep], hub_p[keep], tip_p[keep]
    dq = hub_p - hub_r
    dtip = tip_p - tip_r
    drift = hub_r - motion(t)[0] if t.size else np.empty(0)

    tol_t = 1e-6 * T
    strobe = np.array([abs(dq[int(np.argmin(np.abs(t - k * T)))]) for k in range(completed + 1)]) if t.size else np.empty(0)
    env, tip_env, drift_env = [], [], []
    for k in range(completed):
        sel = (t >= k * T - tol_t) & (t <= (k + 1) * T + tol_t)
        env.append(float(np.max(np.abs(dq[sel]))))
        tip_env.append(float(np.max(np.abs(dtip[sel]))))
        drift_env.append(float(np.max(np.abs(drift[sel]))))
    env_a, tip_a, drift_a = np.array(env), np.array(tip_env), np.array(drift_env)

    outside = (np.abs(dq) > linear_range_angle) | (np.abs(drift) > linear_range_angle)
    if np.any(outside):
        i = int(np.argmax(outside))
        lin_left_at: Optional[float] = float(t[i])
        lin_left_period: Optional[int] = int(math.floor(t[i] / T + 1e-9))
        linear_periods = lin_left_period
    else:
        lin_left_at, lin_left_period = None, None
        linear_periods = completed
    fit_idx = np.arange(1, linear_periods + 1)
    ratio_strobe = _fit_ratio(strobe[fit_idx], fit_idx) if fit_idx.size else math.nan
    env_idx = np.arange(1, linear_periods)
    ratio_env = _fit_ratio(env_a[env_idx], env_idx) if env_idx.size else math.nan
    ratios = strobe[2: linear_periods + 1] / strobe[1: linear_periods] if linear_periods >= 2 else np.empty(0)
    last_ratio = float(ratios[-1]) if ratios.size else math.nan
    prediction = None
    lin_strobe = np.empty(0)
    lin_ratio = math.nan
    if linear:
        prediction = _propagate(exudyn_result.linearization, perturbation, periods, DEFAULT_PREDICTION_STEPS, rho_exudyn)
        lin_strobe = prediction.stroboscopic
        if fit_idx.size:
            lin_ratio = _fit_ratio(lin_strobe[fit_idx], fit_idx)
    rel_ex = ratio_strobe / rho_exudyn - 1.0 if math.isfinite(ratio_strobe) else math.nan
    rel_red = ratio_strobe / rho_reduced - 1.0 if math.isfinite(ratio_strobe) else math.nan
    timings["total"] = time.perf_counter() - t_total
    if diverged:
        logger.warning("validation (Omega=%.4g, kp=%g, kd=%g): diverged: %s", omega, kp, kd, reason)
    logger.info(
        "validation (Omega=%.4g, kp=%g, kd=%g, %d el.): measured %.6g per period, predicted %.6g (Exudyn), %.6g (reduced)",
        omega, kp, kd, elements, ratio_strobe, rho_exudyn, rho_reduced,
    )
    return ValidationResult(
        omega=omega,
        kp=kp,
        kd=kd,
        elements=elements,
        periods=periods,
        periods_completed=completed,
        perturbation=perturbation,
        step=step,
        period=T,
        predicted_multiplier_reduced=rho_reduced,
        predicted_multiplier_exudyn=rho_exudyn,
        predicted_mode_exudyn=str(exudyn_result.dominant_mode),
        spectral_radius_exudyn=float(exudyn_result.floquet.spectral_radius),
        measured_ratio_per_period=ratio_strobe,
        measured_ratio_envelope=ratio_env,
        ratios=ratios,
        stroboscopic=strobe,
        envelope=env_a,
        tip_envelope=tip_a,
        reference_drift=drift_a,
        fit_periods=tuple(int(k) for k in fit_idx if strobe[k] > NOISE_FLOOR),
        linear_range_left_at=lin_left_at,
        linear_range_left_period=lin_left_period,
        linear_range_angle=linear_range_angle,
        diverged=diverged,
        diverged_at=diverged_at,
        reason=reason,
        relative_error_exudyn=rel_ex,
        relative_error_reduced=rel_red,
        agrees=bool(math.isfinite(rel_ex) and abs(rel_ex) <= AGREEMENT_TOLERANCE),
        last_ratio=last_ratio,
        linear_stroboscopic=lin_strobe,
        linear_ratio_per_period=lin_ratio,
        times=t,
        hub_error=dq,
        tip_error=dtip,
        drift=drift,
        timings=timings,
        exudyn=exudyn_result,
        params=params,
        prediction=prediction,
    )


# --------------------------------------------------------------------------- linear prediction
@dataclass(frozen=True)
class LinearPrediction:
    """Response of the linearised Exudyn system to the same initial perturbation.

    Attributes
    ----------
    t : ndarray, shape (m,)
        Times ``j h``, ``h = T / steps_per_period``, over ``periods`` periods.
    hub_error, tip_error : ndarray, shape (m,)
        ``y_1`` (hub angle, rad) and the tip deflection (m) of the linear response.
    stroboscopic : ndarray, shape (periods + 1,)
        ``|y_1(k T)|``.
    modulus : float
        ``|rho|`` of the dominant multiplier used for the envelope.
    envelope_constant : float
        ``C`` of the envelope ``C |rho|^(t/T)`` of the hub error
        (:func:`stability.response.envelope_constant` from ``t = T``).
    steps_per_period : int
    wall_time : float
    """

    t: np.ndarray
    hub_error: np.ndarray
    tip_error: np.ndarray
    stroboscopic: np.ndarray
    modulus: float
    envelope_constant: float
    steps_per_period: int
    wall_time: float

    def envelope(self, t: np.ndarray) -> np.ndarray:
        """``C |rho|^(t/T)`` at ``t``."""
        T = self.t[self.steps_per_period] if self.t.size > self.steps_per_period else math.nan
        return self.envelope_constant * self.modulus ** (np.asarray(t, dtype=float) / T)


def linear_prediction(
    result: ValidationResult,
    *,
    periods: Optional[int] = None,
    steps_per_period: int = DEFAULT_PREDICTION_STEPS,
) -> LinearPrediction:
    """Linear response ``x' = P(t) x``, ``x(0) = perturbation e_{q_a'}``, of the Exudyn linearisation.

    See the module notes for why the exponential midpoint product is used
    instead of :func:`stability.response.linear_response`.

    Parameters
    ----------
    result : ValidationResult
        Supplies the linearisation (``result.exudyn.linearization``), the
        perturbation and the predicted multiplier.
    periods : int, optional
        Default ``result.periods``.
    steps_per_period : int
        Exponential-midpoint steps per period (>= 8).

    Returns
    -------
    LinearPrediction
    """
    periods = result.periods if periods is None else _check_int("periods", periods)
    steps_per_period = _check_int("steps_per_period", steps_per_period, minimum=8)
    if (result.prediction is not None and result.prediction.steps_per_period == steps_per_period
            and result.prediction.stroboscopic.size == periods + 1):
        return result.prediction
    return _propagate(result.exudyn.linearization, result.perturbation, periods, steps_per_period,
                      result.predicted_multiplier_exudyn)


def _propagate(lin: Any, perturbation: float, periods: int, steps_per_period: int, rho: float) -> LinearPrediction:
    """Exponential-midpoint response of ``lin`` from ``x(0) = perturbation e_{q_a'}``."""
    from stability.magnus import MAGNUS2, magnus_factors
    from stability.response import envelope_constant

    tic = time.perf_counter()
    n = lin.size
    T = lin.period
    E = magnus_factors(MAGNUS2, lin.evaluate, T, steps_per_period)
    x = np.zeros(2 * n)
    x[n] = perturbation  # hub velocity (independent coordinate 0)
    X = np.empty((periods * steps_per_period + 1, 2 * n))
    X[0] = x
    i = 0
    for _ in range(periods):
        for j in range(steps_per_period):
            x = E[j] @ x
            i += 1
            X[i] = x
    t = np.arange(X.shape[0]) * (T / steps_per_period)
    hub = X[:, 0].copy()
    tip = X[:, n - 3].copy()  # tip y in the hub frame (see ExudynLinkModel.tip_deflection)
    strobe = np.abs(hub[::steps_per_period])
    C = envelope_constant(t, hub, rho, T, t_from=min(T, t[-1]))
    return LinearPrediction(
        t=t,
        hub_error=hub,
        tip_error=tip,
        stroboscopic=strobe,
        modulus=rho,
        envelope_constant=float(C),
        steps_per_period=steps_per_period,
        wall_time=time.perf_counter() - tic,
    )
