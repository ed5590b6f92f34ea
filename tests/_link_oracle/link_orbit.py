"""The T-periodic motion of the Exudyn link with the hub on its fundamental motion.

Hand-derived route (hub-frame coordinates of :mod:`_link_oracle.exudyn_link`): kept as the
independent check of the generic model-file path (``linearize.analyze("single-link", ...)``,
``tests/test_model_file.py``), which is the package's route for any model.

The undeformed rigid motion is *not* a solution of the ANCF equations:
centrifugal and gravity loads prestress and bend the link.  The true periodic
solution with the hub angle prescribed, ``q_a(t) = q_a^R(t)``, is found here,
together with the hub torque it needs.  With that torque as feed-forward the
same motion is also the periodic orbit of the free hub under any PD gains
(the PD error is zero along it), so one orbit serves the open and the closed
loop.

Method
------
Trigonometric collocation (the periodic counterpart of multiple shooting):
the beam coordinates are unknown at ``N`` equispaced times over one period,
rates and accelerations are their spectral derivatives, and Newton's method
drives Exudyn's projected residual (:meth:`ExudynLinkModel.residual`) to zero
at all ``N`` times at once.  The Newton matrix has the blocks
``K_k delta_km + C_k D1_km + M_k D2_km`` (the finite-difference linearisation
at the samples), so the converged orbit comes with its linearisation.

The result is then checked by *shooting with Exudyn itself*: the prescribed-hub
model is integrated over one period from the orbit's state at ``t = 0`` and the
defect ``x(T) - x(0)`` is reported relative to the elastic deformation
(:attr:`PeriodicOrbit.shooting_residual`).  Part of that defect is the
integrator's own error (generalised-alpha, h = 1e-3).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np
import scipy.linalg

from linearize.finite_difference import central_difference_jacobians
from linearize.fourier import TrigInterpolant, differentiation_matrices, sample_times, trig_interpolate
from _link_oracle.exudyn_link import ExudynLinkConfig, ExudynLinkModel, build_link_model
from mbs_models.parameters import ManipulatorParameters

__all__ = [
    "DEFAULT_SAMPLES",
    "OrbitConvergenceError",
    "PeriodicOrbit",
    "find_periodic_orbit",
    "rigid_reference",
]

logger = logging.getLogger(__name__)

#: Default collocation points per period (the response is dominated by the
#: first few harmonics of Omega; 64 resolves it to round-off, see notes).
DEFAULT_SAMPLES = 64
#: Newton stops when the relative residual is below this.  The attainable floor
#: is ~1e-7: the axial stiffness EA/l_e ~ 2.5e8 N/m times the round-off of
#: coordinates of size ~1 m gives force errors ~3e-8 N against applied forces
#: ~0.5 N (measured: Newton stalls at 1e-7 with 8 elements).
DEFAULT_TOLERANCE = 1e-6
#: ... or when the Newton update is below this fraction of the link length
#: (round-off level for coordinates of size l).
UPDATE_TOLERANCE = 1e-13
#: Maximum Newton iterations.
DEFAULT_MAX_ITERATIONS = 30
#: Above this relative residual the Newton matrix is rebuilt every iteration.
CHORD_THRESHOLD = 1e-3
#: Continuation in Omega: first factor, first increment, smallest increment, budget.
CONTINUATION_START = 0.5
CONTINUATION_STEP = 0.1
CONTINUATION_MIN_STEP = 1e-3
CONTINUATION_MAX_SOLVES = 60
#: Newton gives up when, after this many iterations, the residual is still above
#: its initial value.
STAGNATION_ITERATIONS = 8
#: Step halvings of the backtracking line search.
MAX_STEP_HALVINGS = 12


class OrbitConvergenceError(RuntimeError):
    """The periodic-orbit Newton iteration did not converge (message gives the residuals)."""

    def __init__(self, message: str, residuals: list) -> None:
        super().__init__(message)
        self.residuals = list(residuals)


@dataclass(frozen=True)
class PeriodicOrbit:
    """A T-periodic motion of the link, sampled in independent coordinates.

    Attributes
    ----------
    period : float
        ``T = 2 pi / Omega``.
    times : ndarray, shape (N,)
        Sample times ``k T / N``.
    positions, velocities, accelerations : ndarray, shape (N, n)
        Independent coordinates (see :class:`~_link_oracle.exudyn_link.ExudynLinkModel`)
        and their first and second time derivatives at ``times``.
    hub_torques : ndarray, shape (N,)
        Hub torque the motion needs (N m) at ``times``, joint damping included.
    residual : float
        Max-norm of the projected residual of the beam equations at the
        samples, relative to the max-norm of the generalised applied forces.
        For :func:`rigid_reference` this measures how far the rigid motion is
        from a solution.
    shooting_residual : float
        ``max|x(T) - x(0)| / max|x(0) - x_rigid(0)|`` of a one-period Exudyn
        simulation from the orbit's initial state (NaN if not checked).
    iterations : int
        Newton iterations used (0 for the rigid reference).
    kind : str
        ``"periodic"`` (a solution) or ``"rigid"`` (undeformed reference).
    config : ExudynLinkConfig
        Model configuration (elements, Omega, ...).
    params : ManipulatorParameters
        Physical data.
    wall_time : float
        Seconds spent.
    """

    period: float
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    hub_torques: np.ndarray
    residual: float
    shooting_residual: float
    iterations: int
    kind: str
    config: ExudynLinkConfig
    params: ManipulatorParameters = field(repr=False)
    wall_time: float = 0.0

    @property
    def samples(self) -> int:
        """Number of samples per period."""
        return int(self.times.size)

    def state(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, rates and accelerations at ``t`` (trigonometric interpolation)."""
        return (
            trig_interpolate(self.positions, self.period, t),
            trig_interpolate(self.velocities, self.period, t),
            trig_interpolate(self.accelerations, self.period, t),
        )

    def hub_torque(self, t: float | np.ndarray) -> float | np.ndarray:
        """Feed-forward hub torque ``tau_ff(t)`` in N m (periodic interpolation).

        The interpolant's coefficients are computed at the first call and kept (this is the load
        user function of every closed-loop Exudyn run: one call per Newton iteration).
        """
        f = self.__dict__.get("_hub_torque_interpolant")
        if f is None:
            f = TrigInterpolant(self.hub_torques, self.period)
            object.__setattr__(self, "_hub_torque_interpolant", f)
        return f(t)

    def tip_deflection(self) -> np.ndarray:
        """Tip deflection normal to the rigid line at the samples (m)."""
        return self.positions[:, -3].copy()  # tip y in the hub frame

    def summary(self) -> dict:
        """JSON-ready summary."""
        d = self.tip_deflection()
        return {
            "kind": self.kind,
            "elements": self.config.elements,
            "omega": self.config.omega,
            "samples": self.samples,
            "orbit_residual": float(self.residual),
            "shooting_residual": float(self.shooting_residual),
            "iterations": self.iterations,
            "tip_deflection_min": float(d.min()),
            "tip_deflection_max": float(d.max()),
            "hub_torque_max": float(np.max(np.abs(self.hub_torques))),
        }


def _evaluation_model(params: ManipulatorParameters, config: ExudynLinkConfig) -> ExudynLinkModel:
    """Free-hub model without drive: its residual row 0 is the needed hub torque."""
    return build_link_model(params, replace(config, drive="free", kp=0.0, kd=0.0))


def _hub_motion(config: ExudynLinkConfig, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from _link_oracle.exudyn_link import fundamental_motion

    return fundamental_motion(config)(times)


def _rigid_samples(model: ExudynLinkModel, times: np.ndarray) -> np.ndarray:
    th, thd, _ = _hub_motion(model.config, times)
    return np.array([model.rigid_configuration(float(a))[0] for a in th])


def _force_scale(model: ExudynLinkModel, P, V, times) -> float:
    scale = 0.0
    for k in range(times.size):
        J = model.jacobian(P[k])
        f = J.T @ model.rhs(model.coordinates(P[k]), J @ V[k], times[k])
        scale = max(scale, float(np.max(np.abs(f[1:]))))
    return scale if scale > 0 else 1.0


def _residuals(model, P, V, A, times) -> np.ndarray:
    return np.array([model.residual(P[k], V[k], A[k], times[k]) for k in range(times.size)])


def rigid_reference(
    params: Optional[ManipulatorParameters] = None,
    config: Optional[ExudynLinkConfig] = None,
    *,
    samples: int = DEFAULT_SAMPLES,
) -> PeriodicOrbit:
    """The undeformed rigid fundamental motion as a (non-solution) reference orbit.

    Useful only to show what linearising about it gets wrong; its
    ``residual`` says how far it is from satisfying the beam equations.
    """
    tic = time.perf_counter()
    params = ManipulatorParameters() if params is None else params
    config = ExudynLinkConfig() if config is None else config
    model = _evaluation_model(params, config)
    T = config.period
    times = sample_times(T, samples)
    D1, D2 = differentiation_matrices(T, samples)
    P = _rigid_samples(model, times)
    V, A = D1 @ P, D2 @ P
    R = _residuals(model, P, V, A, times)
    scale = _force_scale(model, P, V, times)
    return PeriodicOrbit(
        period=T,
        times=times,
        positions=P,
        velocities=V,
        accelerations=A,
        hub_torques=R[:, 0].copy(),
        residual=float(np.max(np.abs(R[:, 1:])) / scale),
        shooting_residual=math.nan,
        iterations=0,
        kind="rigid",
        config=config,
        params=params,
        wall_time=time.perf_counter() - tic,
    )


def _newton(model, P, times, D1, D2, scale, tol, max_iterations, length):
    """Damped Newton on the collocation equations; returns (P, history, converged)."""
    N, nb = P.shape[0], model.n - 1
    th, thd, thdd = _hub_motion(model.config, times)
    history: list = []
    lu = None
    for it in range(1, int(max_iterations) + 1):
        V, A = D1 @ P, D2 @ P
        V[:, 0], A[:, 0] = thd, thdd  # hub exactly on the fundamental motion
        R = _residuals(model, P, V, A, times)[:, 1:]
        res = float(np.max(np.abs(R))) / scale
        history.append(res)
        logger.debug("orbit Newton %d: relative residual %.3e", it, res)
        if not np.isfinite(res):
            return P, history, False
        if res <= tol:
            return P, history, True
        if it > STAGNATION_ITERATIONS and res > history[0]:
            return P, history, False  # diverging: give up early (continuation may help)
        # full Newton while far away, chord iterations (reused LU) close to the orbit
        if lu is None or res > CHORD_THRESHOLD or (len(history) >= 2 and history[-1] > 0.1 * history[-2]):
            big = np.zeros((N, nb, N, nb))
            for k in range(N):
                K, C = central_difference_jacobians(
                    model.residual, P[k], V[k], A[k], times[k], columns=slice(1, None), rows=slice(1, None)
                )
                Mk = model.reduced_mass(P[k])[1:, 1:]
                big[k, :, k, :] += K
                big[k, :, :, :] += D1[k][None, :, None] * C[:, None, :] + D2[k][None, :, None] * Mk[:, None, :]
            lu = scipy.linalg.lu_factor(big.reshape(N * nb, N * nb), check_finite=False)
        dZ = scipy.linalg.lu_solve(lu, -R.reshape(-1), check_finite=False).reshape(N, nb)
        # damped Newton with Deuflhard's natural monotonicity test: the residual is
        # measured through the Newton matrix (a displacement), so that the stiff
        # axial terms (foreshortening under bending) do not dominate the merit
        lam = 1.0
        step_norm = float(np.max(np.abs(dZ)))
        for _ in range(MAX_STEP_HALVINGS):
            trial = P.copy()
            trial[:, 1:] += lam * dZ
            Vt, At = D1 @ trial, D2 @ trial
            Vt[:, 0], At[:, 0] = thd, thdd
            Rt = _residuals(model, trial, Vt, At, times)[:, 1:]
            if np.all(np.isfinite(Rt)):
                simplified = scipy.linalg.lu_solve(lu, -Rt.reshape(-1), check_finite=False)
                if float(np.max(np.abs(simplified))) <= (1.0 - 0.25 * lam) * step_norm:
                    break
            lam *= 0.5
        P = trial
        P[:, 0] = th
        if lam < 1.0:
            logger.debug("orbit Newton %d: step damped to %.3g", it, lam)
        if float(np.max(np.abs(lam * dZ))) <= UPDATE_TOLERANCE * length and res <= 1e3 * tol:
            return P, history, True  # round-off level reached
    return P, history, False


def _continuation(params, config, times_target, D1_target, D2_target, tol, max_iterations):
    """Natural-parameter continuation in Omega from Omega/2 (phase-aligned samples)."""
    N = times_target.size
    f, step, P, history = CONTINUATION_START, CONTINUATION_STEP, None, []
    solves = 0
    while solves < CONTINUATION_MAX_SOLVES:
        target = min(1.0, f)
        cfg = replace(config, omega=config.omega * target)
        model = _evaluation_model(params, cfg)
        T = cfg.period
        times = sample_times(T, N)
        D1, D2 = differentiation_matrices(T, N)
        guess = _rigid_samples(model, times) if P is None else P.copy()
        th, _, _ = _hub_motion(cfg, times)
        guess[:, 0] = th
        scale = _force_scale(model, guess, D1 @ guess, times)
        Pn, hist, ok = _newton(model, guess, times, D1, D2, scale, tol, max_iterations, params.length)
        history += hist
        solves += 1
        logger.debug("orbit continuation: Omega factor %.4f %s", target, "converged" if ok else "failed")
        if ok:
            P = Pn
            if target >= 1.0:
                return P, history, True
            step *= 1.5
            f = target + step
        else:
            if P is None:
                f *= 0.5  # start lower
            else:
                step *= 0.5
                f = f - step
                if step < CONTINUATION_MIN_STEP:
                    break
    return (P if P is not None else _rigid_samples(_evaluation_model(params, config), times_target)), history, False


def find_periodic_orbit(
    params: Optional[ManipulatorParameters] = None,
    config: Optional[ExudynLinkConfig] = None,
    *,
    samples: int = DEFAULT_SAMPLES,
    tol: float = DEFAULT_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    verify: bool = True,
    continuation: bool = True,
) -> PeriodicOrbit:
    """T-periodic motion of the link with the hub on ``q_a^R(t)``, and its hub torque.

    Parameters
    ----------
    params : ManipulatorParameters, optional
        Physical data (default Table 1).
    config : ExudynLinkConfig, optional
        Elements, Omega, damping, gravity; ``drive``, ``kp`` and ``kd`` are
        ignored (the orbit is the same for every drive, see the module notes).
    samples : int
        Collocation points per period (even, >= 4).
    tol : float
        Relative residual at which Newton stops.
    max_iterations : int
        Newton iterations before :class:`OrbitConvergenceError`.
    verify : bool
        Integrate one period with Exudyn from the orbit's initial state and
        report the periodicity defect (:attr:`PeriodicOrbit.shooting_residual`).
    continuation : bool
        If Newton from the rigid motion fails, continue in Omega from a lower
        frequency (the response grows with Omega^2 and near resonances of the
        harmonics; measured: needed at Omega = 8 pi).

    Returns
    -------
    PeriodicOrbit

    Raises
    ------
    OrbitConvergenceError
        If Newton does not reach ``tol`` within ``max_iterations`` (the message
        lists the residual history), or produces non-finite iterates.
    ValueError
        On invalid arguments.
    """
    tic = time.perf_counter()
    params = ManipulatorParameters() if params is None else params
    config = ExudynLinkConfig() if config is None else config
    if not (math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be finite and > 0, got {tol!r}")
    if isinstance(max_iterations, bool) or int(max_iterations) != max_iterations or max_iterations < 1:
        raise ValueError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    model = _evaluation_model(params, config)
    T = config.period
    times = sample_times(T, samples)
    D1, D2 = differentiation_matrices(T, samples)
    th, thd, thdd = _hub_motion(config, times)

    P = _rigid_samples(model, times)
    scale = _force_scale(model, P, D1 @ P, times)
    P, history, ok = _newton(model, P, times, D1, D2, scale, tol, max_iterations, params.length)
    iterations = len(history)
    if not ok and continuation:
        logger.info("orbit: Newton from the rigid motion failed; continuation in Omega")
        P, hist2, ok = _continuation(params, config, times, D1, D2, tol, max_iterations)
        history = history + hist2
        iterations = len(history)
    if not ok:
        raise OrbitConvergenceError(
            f"periodic orbit did not converge in {max_iterations} Newton iterations "
            f"(relative residuals {', '.join(f'{r:.2e}' for r in history[-12:])}; tolerance {tol:.1e})"
            + ("" if not continuation else " even with continuation in Omega")
            + "; try more samples, structural damping, or check that Omega is not at a resonance",
            history,
        )
    V, A = D1 @ P, D2 @ P
    V[:, 0], A[:, 0] = thd, thdd
    Rfull = _residuals(model, P, V, A, times)
    residual = float(np.max(np.abs(Rfull[:, 1:]))) / scale
    shooting = math.nan
    if verify:
        shooting = _shooting_defect(params, config, P[0], V[0], model)
    logger.info(
        "periodic orbit (%d elements, Omega=%.4g): residual %.2e after %d iterations, shooting defect %.2e",
        config.elements, config.omega, residual, iterations, shooting,
    )
    return PeriodicOrbit(
        period=T,
        times=times,
        positions=P,
        velocities=V,
        accelerations=A,
        hub_torques=Rfull[:, 0].copy(),
        residual=residual,
        shooting_residual=shooting,
        iterations=iterations,
        kind="periodic",
        config=config,
        params=params,
        wall_time=time.perf_counter() - tic,
    )


def _shooting_defect(params, config, p0, v0, model) -> float:
    """One-period Exudyn run (hub prescribed) from ``(p0, v0)``: relative periodicity defect."""
    sim_model = build_link_model(params, replace(config, drive="prescribed"))
    res = sim_model.simulate(p0, v0, config.period)
    x0 = np.concatenate([p0, v0])
    xT = res.final_state
    pr, vr = model.rigid_configuration(float(p0[0]), float(v0[0]))
    elastic = np.max(np.abs(x0 - np.concatenate([pr, vr])))
    return float(np.max(np.abs(xT - x0)) / max(elastic, 1e-300))
