"""Direct monodromy of any model file: finite differences of one-period Exudyn runs.

An independent check of the linearisation + Floquet path: the
model file is built afresh, each drive is released and driven inside Exudyn
by ``tau = tau_ff(t) - kp (q - q^R) - kd (q' - q^R')`` (one
``CoordinateSpringDamper`` per drive whose spring-force user function adds
the feed-forward; ``stiffness = kp`` and ``damping = kd`` are the values
Exudyn's Newton Jacobian uses), and Exudyn's own generalised-alpha
integrator maps a state at ``t = 0`` to ``t = T``.

Coordinates: the perturbations live in an orthonormal basis ``N`` of the null
space of the model's constraint Jacobian at the orbit state (SVD), positions
``q0 + eps N z`` and rates ``v0 + N z'``; the end states are projected back
with ``N^T`` (the orbit is T-periodic, so the same basis holds at ``T``).
Column ``i`` of the monodromy is ``(x_i(T) - x_0(T)) / eps`` (forward
differences of the discrete map).  Multipliers are independent of the basis.

Error budget: forward differences err by ``O(eps |Phi''|)`` and by the
integrator's Newton tolerance over ``eps`` (``1e-10 / 1e-6 = 1e-4`` relative
to the columns at worst); generalised alpha (2nd order, ``h = 1e-3``) shifts
a multiplier of a mode of frequency ``w`` by about ``(w h)^2 / 12`` of its
phase per period.  For the dominant (slow) modes both stay well below 1e-3.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np

from mbs_models.model_file import Drive

__all__ = ["DirectMonodromy", "direct_monodromy", "DIRECT_EPSILON", "DIRECT_STEP"]

logger = logging.getLogger(__name__)

#: Perturbation size (m, rad, m/s, rad/s): large against the Newton tolerance
#: of the runs (1e-10 absolute), small against the elastic deformations (~1e-3 m).
DIRECT_EPSILON = 1e-6
#: Generalised-alpha step (s) and spectral radius at infinity.
DIRECT_STEP = 1e-3
DIRECT_SPECTRAL_RADIUS = 0.9
#: Singular values of C_q below this times the largest are zero (trivial joint rows).
NULL_SPACE_RTOL = 1e-10


@dataclass(frozen=True)
class DirectMonodromy:
    """Monodromy of Exudyn's discrete one-period map in null-space coordinates.

    Attributes
    ----------
    multipliers : ndarray
        Eigenvalues, sorted by modulus, descending.
    monodromy : ndarray, shape (2 r, 2 r)
    basis : ndarray, shape (n, r)
        Orthonormal null-space basis ``N`` at the orbit state.
    defect : float
        ``max |x_0(T) - x_0(0)|`` of the unperturbed run relative to the
        state's variation scale (how well the given orbit closes in Exudyn).
    simulations : int
    wall_time : float
    """

    multipliers: np.ndarray
    monodromy: np.ndarray = field(repr=False)
    basis: np.ndarray = field(repr=False)
    defect: float
    simulations: int
    epsilon: float
    step: float
    wall_time: float

    def nearest(self, mu: complex) -> complex:
        """The multiplier closest to ``mu``."""
        return complex(self.multipliers[int(np.argmin(np.abs(self.multipliers - mu)))])


def _settings(T: float, step: float, spectral_radius: float):
    import exudyn as exu

    s = exu.SimulationSettings()
    s.timeIntegration.startTime = 0.0
    s.timeIntegration.endTime = float(T)
    s.timeIntegration.numberOfSteps = max(1, int(round(T / step)))
    s.timeIntegration.generalizedAlpha.spectralRadius = float(spectral_radius)
    s.timeIntegration.verboseMode = 0
    s.timeIntegration.automaticStepSize = False
    s.timeIntegration.newton.relativeTolerance = 1e-8
    s.timeIntegration.newton.absoluteTolerance = 1e-10
    s.solution.file.write = False
    s.solution.file.writeInitialValues = False
    s.show.statistics = False
    s.show.computationTime = False
    s.linearSolver.solverType = exu.LinearSolverType.EigenDense
    return s


def _constraint_null_space(mbs: Any, q0: np.ndarray, settings: Any) -> np.ndarray:
    """Orthonormal basis of ``null C_q(q0, 0)`` of the assembled ``mbs`` (identity without constraints).

    ``C_q`` is Exudyn's own algebraic-equation Jacobian, evaluated by a solver initialised
    with ``settings`` at the state ``(q0, 0)``, ``t = 0``; rank by :data:`NULL_SPACE_RTOL`.
    """
    import exudyn as exu

    n = mbs.systemData.ODE2Size()
    solver = exu.MainSolverImplicitSecondOrder()
    solver.InitializeSolver(mbs, settings)
    sd = mbs.systemData
    cur = exu.ConfigurationType.Current
    sd.SetODE2Coordinates(q0, configuration=cur)
    sd.SetODE2Coordinates_t(np.zeros(n), configuration=cur)
    sd.SetTime(0.0, cur)
    solver.ComputeJacobianODE2RHS(mbs, scalarFactor_ODE2=0.0, scalarFactor_ODE2_t=0.0, scalarFactor_ODE1=0.0)
    solver.ComputeJacobianAE(mbs, scalarFactor_ODE2=1.0, scalarFactor_ODE2_t=0.0, scalarFactor_ODE1=1.0,
                             velocityLevel=False)
    Cq = np.array(solver.GetSystemJacobian(), dtype=float)[n:, :n]
    if not Cq.size:
        return np.eye(n)
    _, s, Vt = np.linalg.svd(Cq)
    rank = int(np.sum(s > NULL_SPACE_RTOL * s[0])) if s.size else 0
    return Vt[rank:].T


def _gain_list(value: Any, d: int, name: str) -> list[float]:
    vals = [float(value)] * d if np.isscalar(value) else [float(v) for v in value]
    if len(vals) != d:
        raise ValueError(f"{name}: {len(vals)} values for {d} drives")
    return vals


def direct_monodromy(
    build: Callable[..., Sequence[Any]],
    omega: float,
    q0: np.ndarray,
    v0: np.ndarray,
    feedforward: Callable[[float], np.ndarray],
    *,
    kp: "float | Sequence[float]" = 0.0,
    kd: "float | Sequence[float]" = 0.0,
    epsilon: float = DIRECT_EPSILON,
    step: float = DIRECT_STEP,
    spectral_radius: float = DIRECT_SPECTRAL_RADIUS,
    **options: Any,
) -> DirectMonodromy:
    """Monodromy from ``2 r + 1`` one-period Exudyn runs of the closed loop.

    Parameters
    ----------
    build : callable
        The model file's ``build(mbs, omega, **options)``.
    omega : float
    q0, v0 : ndarray, shape (n,)
        Orbit state at ``t = 0`` (Exudyn ODE2 coordinates and rates).
    feedforward : callable
        ``t -> tau_ff(t)``, one torque per drive (positive pushes ``q[m1] - q[m0]`` up).
    kp, kd : float or sequence
        PD gains per drive (or one for all).
    epsilon, step, spectral_radius : float
        Perturbation, integrator step and generalised-alpha spectral radius.
    **options
        Keyword options of ``build``.

    Raises
    ------
    RuntimeError
        If an Exudyn run fails.
    """
    import exudyn as exu
    from exudyn.itemInterface import CoordinateSpringDamper

    tic = time.perf_counter()
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    drives = list(build(mbs, float(omega), **options))
    d = len(drives)
    kps, kds = _gain_list(kp, d, "kp"), _gain_list(kd, d, "kd")
    for i, dr in enumerate(drives):
        drive = Drive.coerce(dr)
        markers, motion = drive.markers, drive.motion

        def force(mbs_, t, item, u, v, k, c, offset, _i=i, _motion=motion):  # noqa: ARG001
            qr, qr_t, _ = _motion(t)
            return k * (u - qr) + c * (v - qr_t) - float(np.asarray(feedforward(t))[_i])

        mbs.AddObject(CoordinateSpringDamper(markerNumbers=list(markers), stiffness=kps[i], damping=kds[i],
                                             springForceUserFunction=force, name=f"drive_{i}"))
    mbs.Assemble()
    n = mbs.systemData.ODE2Size()
    q0 = np.asarray(q0, dtype=float)
    v0 = np.asarray(v0, dtype=float)
    if q0.shape != (n,) or v0.shape != (n,):
        raise ValueError(f"orbit state must have {n} coordinates, got {q0.shape}, {v0.shape}")

    sd = mbs.systemData
    N = _constraint_null_space(mbs, q0, _settings(1.0, step, spectral_radius))
    r = N.shape[1]
    T = 2 * math.pi / float(omega)
    settings = _settings(T, step, spectral_radius)
    ini = exu.ConfigurationType.Initial

    def run(q: np.ndarray, v: np.ndarray) -> np.ndarray:
        sd.SetODE2Coordinates(q, configuration=ini)
        sd.SetODE2Coordinates_t(v, configuration=ini)
        try:
            ok = mbs.SolveDynamic(settings)
        except Exception as exc:  # noqa: BLE001 - Exudyn raises its own error types
            raise RuntimeError(f"Exudyn run of the direct monodromy failed: {' '.join(str(exc).split())}") from None
        qT, vT = np.array(sd.GetODE2Coordinates()), np.array(sd.GetODE2Coordinates_t())
        if ok is False or not (np.all(np.isfinite(qT)) and np.all(np.isfinite(vT))):
            raise RuntimeError("Exudyn run of the direct monodromy did not complete the period")
        return np.concatenate([N.T @ qT, N.T @ vT])

    base = run(q0, v0)
    x0 = np.concatenate([N.T @ q0, N.T @ v0])
    scale = max(1.0, float(np.max(np.abs(v0))) * T)
    defect = float(np.max(np.abs(base - x0))) / scale
    Phi = np.empty((2 * r, 2 * r))
    for i in range(2 * r):
        dq = epsilon * N[:, i] if i < r else np.zeros(n)
        dv = epsilon * N[:, i - r] if i >= r else np.zeros(n)
        Phi[:, i] = (run(q0 + dq, v0 + dv) - base) / epsilon
    mu = np.linalg.eigvals(Phi)
    mu = mu[np.argsort(-np.abs(mu), kind="stable")]
    wall = time.perf_counter() - tic
    logger.info("direct monodromy: %d runs, %d independent coordinates, %.1f s, |rho|max %.6f",
                2 * r + 1, r, wall, abs(mu[0]))
    return DirectMonodromy(multipliers=mu, monodromy=Phi, basis=N, defect=defect, simulations=2 * r + 1,
                           epsilon=float(epsilon), step=float(step), wall_time=wall)
