"""Periodic orbit of a model file by shooting on Exudyn's own integrator (independent of linearize/).

With every drive prescribed (``CoordinateConstraint`` with offset user
functions), the state at ``t = 0`` is found by Newton's method on the
one-period defect ``x(T) - x(0) = 0`` of Exudyn's generalised-alpha map, in
an orthonormal basis ``N`` of the null space of the full constraint Jacobian
(model constraints and drives) at the model's initial state; the Jacobian is
the finite-difference monodromy minus the identity.  The last run records the
drive constraints' reactions, the feed-forward torques (``tau = -lambda``:
Exudyn's ``CoordinateConstraint`` adds ``-lambda`` to ``q[m1]`` and
``+lambda`` to ``q[m0]``).

Used as an independent orbit for :func:`validation.direct_monodromy.direct_monodromy`
and as a cross-check of the collocation orbit of :mod:`linearize.periodic_orbit`.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from mbs_models.model_file import Drive
from validation.direct_monodromy import (DIRECT_EPSILON, DIRECT_SPECTRAL_RADIUS, DIRECT_STEP,
                                         _constraint_null_space, _settings)

__all__ = ["ShootingOrbit", "shooting_orbit", "SHOOTING_TOLERANCE"]

logger = logging.getLogger(__name__)

#: Newton stops when the defect is below this (m, rad, m/s, rad/s).  The runs' own
#: Newton stops at 1e-8 relative, so one-period maps of states of size 1-10 are
#: reproducible to ~1e-8..1e-7 (measured floor on the two-link arm: 1.5e-8); 1e-7
#: is still 10 times below the perturbation of the monodromy (1e-6).
SHOOTING_TOLERANCE = 1e-7


@dataclass(frozen=True)
class ShootingOrbit:
    """A T-periodic state of a model with its drives prescribed, found in Exudyn.

    Attributes
    ----------
    q0, v0 : ndarray, shape (n,)
        ODE2 coordinates and rates at ``t = 0``.
    times : ndarray, shape (m,)
        The recorded times of the last run (``0 .. T``, every step).
    q : ndarray, shape (m, n)
        Coordinates along the orbit.
    torques : ndarray, shape (m, d)
        Feed-forward torque of each drive along the orbit.
    defect : float
        ``max |x(T) - x(0)|`` reached (independent coordinates).
    iterations : int
    wall_time : float
    """

    q0: np.ndarray = field(repr=False)
    v0: np.ndarray = field(repr=False)
    times: np.ndarray = field(repr=False)
    q: np.ndarray = field(repr=False)
    torques: np.ndarray = field(repr=False)
    period: float
    defect: float
    iterations: int
    wall_time: float

    def torque(self, t: float) -> np.ndarray:
        """Feed-forward torques at ``t`` (periodic, linear interpolation between steps)."""
        tt = float(t) % self.period
        return np.array([np.interp(tt, self.times, self.torques[:, j]) for j in range(self.torques.shape[1])])


def shooting_orbit(
    build: Callable[..., Sequence[Any]],
    omega: float,
    *,
    step: float = DIRECT_STEP,
    spectral_radius: float = DIRECT_SPECTRAL_RADIUS,
    epsilon: float = DIRECT_EPSILON,
    tolerance: float = SHOOTING_TOLERANCE,
    max_iterations: int = 10,
    **options: Any,
) -> ShootingOrbit:
    """Newton shooting for the periodic state of ``build`` with its drives prescribed.

    Raises
    ------
    RuntimeError
        If an Exudyn run fails or Newton does not reach ``tolerance`` (the
        message says how far it got).
    """
    import exudyn as exu
    from exudyn.itemInterface import CoordinateConstraint

    tic = time.perf_counter()
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    drives = list(build(mbs, float(omega), **options))
    drive_objects = []
    for dr in drives:
        drive = Drive.coerce(dr)
        markers, motion = drive.markers, drive.motion
        drive_objects.append(mbs.AddObject(CoordinateConstraint(
            markerNumbers=list(markers),
            offsetUserFunction=lambda m, t, i, v, _mo=motion: float(_mo(t)[0]),
            offsetUserFunction_t=lambda m, t, i, v, _mo=motion: float(_mo(t)[1]),
        )))
    mbs.Assemble()
    sd = mbs.systemData
    n = sd.ODE2Size()
    ini = exu.ConfigurationType.Initial
    q0 = np.array(sd.GetODE2Coordinates(configuration=ini))
    v0 = np.array(sd.GetODE2Coordinates_t(configuration=ini))
    T = 2 * math.pi / float(omega)
    settings = _settings(T, step, spectral_radius)
    N = _constraint_null_space(mbs, q0, settings)
    r = N.shape[1]
    record: dict = {"on": False, "t": [], "q": [], "tau": []}

    def post(mbs_, t):
        if record["on"]:
            record["t"].append(t)
            record["q"].append(np.array(mbs_.systemData.GetODE2Coordinates()))
            record["tau"].append([-float(mbs_.GetObjectOutput(o, exu.OutputVariableType.Force)) for o in drive_objects])
        return True

    mbs.SetPostStepUserFunction(post)

    def run(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sd.SetODE2Coordinates(q, configuration=ini)
        sd.SetODE2Coordinates_t(v, configuration=ini)
        try:
            ok = mbs.SolveDynamic(settings)
        except Exception as exc:  # noqa: BLE001
            raise RuntimeError(f"Exudyn run of the shooting orbit failed: {' '.join(str(exc).split())}") from None
        qT, vT = np.array(sd.GetODE2Coordinates()), np.array(sd.GetODE2Coordinates_t())
        if ok is False or not (np.all(np.isfinite(qT)) and np.all(np.isfinite(vT))):
            raise RuntimeError("Exudyn run of the shooting orbit did not complete the period")
        return qT, vT

    q, v = q0.copy(), v0.copy()
    history = []
    J = None
    try:
        for it in range(1, max_iterations + 1):
            qT, vT = run(q, v)
            F = np.concatenate([N.T @ (qT - q), N.T @ (vT - v)])
            defect = float(np.max(np.abs(F))) if F.size else 0.0
            history.append(defect)
            logger.info("shooting iteration %d: defect %.3e", it, defect)
            if defect <= tolerance:
                break
            if J is None or history[-1] > 0.1 * history[-2]:  # chord Newton while it contracts fast
                J = np.empty((2 * r, 2 * r))
                for i in range(2 * r):
                    dq = epsilon * N[:, i] if i < r else np.zeros(n)
                    dv = epsilon * N[:, i - r] if i >= r else np.zeros(n)
                    qi, vi = run(q + dq, v + dv)
                    J[:, i] = (np.concatenate([N.T @ qi, N.T @ vi]) - np.concatenate([N.T @ qT, N.T @ vT])) / epsilon
                J -= np.eye(2 * r)
            dz = np.linalg.solve(J, -F)
            q = q + N @ dz[:r]
            v = v + N @ dz[r:]
        else:
            raise RuntimeError(f"shooting orbit did not converge in {max_iterations} Newton iterations: "
                               f"defects {['%.1e' % h for h in history]}, tolerance {tolerance:.0e}")
        record["on"] = True
        run(q, v)
    finally:
        record["on"] = False
        mbs.SetPostStepUserFunction(0)
    times = np.concatenate([[0.0], np.asarray(record["t"])])
    qs = np.vstack([q, np.asarray(record["q"])])
    taus = np.asarray(record["tau"])
    taus = np.vstack([taus[-1:], taus])  # t = 0 equals t = T on the orbit
    return ShootingOrbit(q0=q, v0=v, times=times, q=qs, torques=taus, period=T, defect=history[-1],
                         iterations=len(history), wall_time=time.perf_counter() - tic)
