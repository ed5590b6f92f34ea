"""Finite-difference monodromy of the nonlinear slider-crank (constant crank speed), from Exudyn runs alone.

Independent of the package's orbit, linearisation and Floquet code: only the model file's ``build`` and
Exudyn's own integrator are used.  With the crank angle prescribed (``form="constraint"``: a rheonomic
``CoordinateConstraint`` ``theta = Omega t``), every constraint is linear in the rod's coordinates -- the pin
position depends on ``theta`` only, the guide fixes the last node's ``y`` -- so the free coordinates are a
fixed selection of ODE2 coordinates (:data:`FREE`), perturbed without leaving the constraint manifold.

1. The orbit: Newton on the one-period map ``x -> F(x)`` of the free positions and rates (shooting, the
   Jacobian from the same central differences), from the state after a few periods of the file's
   initial motion, until ``|F(x) - x|`` stops falling.
2. The monodromy: central differences of ``F`` at the orbit (``EPS`` on positions, ``EPS * Omega_ref`` on
   rates), at the trapezoidal rule (generalised alpha, spectral radius 1, second order) with ``steps``,
   ``2 steps`` and ``4 steps`` per period; multipliers Richardson-extrapolated (``(4 m_2h - m_h) / 3`` per
   level pair, twice) with the last change as the error estimate.
"""
from __future__ import annotations

import math

import numpy as np

#: Free ODE2 coordinates of the 2-element rod (crank node 0..2 and the pin node's position 3, 4 are fixed;
#: 12 is the slider's y): slopes of node 0, all of node 1, x and slopes of node 2.
FREE = np.array([5, 6, 7, 8, 9, 10, 11, 13, 14])
#: Central-difference step on positions (m, slope units); rates get EPS times the first bending frequency.
#: Large against the runs' Newton tolerance (1e-10), small against the rod's deformation; the central
#: difference's own error is O(EPS^2) of the map's curvature.
EPS = 1e-5


def _system(omega: float):
    import exudyn as exu

    from mbs_models.builtin.slider_crank import build  # the model under test, nothing else of the package

    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    build(mbs, omega, form="constraint", elements=2)
    mbs.Assemble()
    return sc, mbs


def _settings(T: float, steps: int):
    import exudyn as exu

    s = exu.SimulationSettings()
    s.timeIntegration.startTime = 0.0
    s.timeIntegration.endTime = T
    s.timeIntegration.numberOfSteps = int(steps)
    s.timeIntegration.generalizedAlpha.spectralRadius = 1.0
    s.timeIntegration.verboseMode = 0
    s.timeIntegration.automaticStepSize = False
    s.timeIntegration.newton.relativeTolerance = 1e-10
    s.timeIntegration.newton.absoluteTolerance = 1e-10
    s.timeIntegration.newton.useModifiedNewton = False
    s.solution.file.write = False
    s.solution.file.writeInitialValues = False
    s.show.statistics = False
    s.show.computationTime = False
    s.linearSolver.solverType = exu.LinearSolverType.EigenDense
    return s


class OnePeriodMap:
    """``(q, v)`` at ``t = 0`` -> ``(q, v)`` at ``t = T`` of the constant-speed slider-crank (Exudyn runs)."""

    def __init__(self, omega: float, steps: int):
        import exudyn as exu

        self.omega, self.T = float(omega), 2 * math.pi / float(omega)
        self.sc, self.mbs = _system(omega)
        self.settings = _settings(self.T, steps)
        sd = self.mbs.systemData
        ini = exu.ConfigurationType.Initial
        self.q_file = np.array(sd.GetODE2Coordinates(configuration=ini))
        self.v_file = np.array(sd.GetODE2Coordinates_t(configuration=ini))
        self._exu = exu

    def __call__(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        exu, sd = self._exu, self.mbs.systemData
        ini, cur = exu.ConfigurationType.Initial, exu.ConfigurationType.Current
        sd.SetODE2Coordinates(q, configuration=ini)
        sd.SetODE2Coordinates_t(v, configuration=ini)
        if not self.mbs.SolveDynamic(self.settings):
            raise RuntimeError("Exudyn's integrator failed")
        qT = np.array(sd.GetODE2Coordinates(configuration=cur))
        vT = np.array(sd.GetODE2Coordinates_t(configuration=cur))
        qT[2] -= 2 * math.pi  # the crank made one turn
        return qT, vT

    def reduced(self, x: np.ndarray, base: tuple) -> np.ndarray:
        """The map on the free coordinates ``x = (q_free, v_free)``, the rest from ``base``."""
        q, v = base[0].copy(), base[1].copy()
        q[FREE], v[FREE] = x[:FREE.size], x[FREE.size:]
        qT, vT = self(q, v)
        return np.concatenate([qT[FREE], vT[FREE]])


def monodromy(F: OnePeriodMap, x: np.ndarray, base: tuple, rate_scale: float) -> np.ndarray:
    n = x.size
    h = np.where(np.arange(n) < FREE.size, EPS, EPS * rate_scale)
    cols = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = h[j]
        cols.append((F.reduced(x + e, base) - F.reduced(x - e, base)) / (2 * h[j]))
    return np.array(cols).T


def orbit(omega: float, steps: int, rate_scale: float = 1300.0, transient_periods: int = 4,
          iterations: int = 4) -> tuple:
    """``(x, base, Phi, defect)``: the periodic state (free coordinates), the full base state, the monodromy
    at it and ``|F(x) - x|`` (max norm) before the last Newton step."""
    F = OnePeriodMap(omega, steps)
    q, v = F.q_file.copy(), F.v_file.copy()
    for _ in range(transient_periods):
        q, v = F(q, v)
    base = (q, v)
    x = np.concatenate([q[FREE], v[FREE]])
    defect = math.inf
    Phi = None
    for _ in range(iterations):
        r = F.reduced(x, base) - x
        d = float(np.max(np.abs(r)))
        Phi = monodromy(F, x, base, rate_scale)
        if d >= defect:
            break
        defect = d
        x = x - np.linalg.solve(Phi - np.eye(x.size), r)
    return x, base, Phi, defect


def _match(ref: np.ndarray, other: np.ndarray) -> np.ndarray:
    out = []
    pool = list(other)
    for m in ref:
        j = int(np.argmin([abs(m - p) for p in pool]))
        out.append(pool.pop(j))
    return np.array(out)


def multipliers(omega: float, steps: int = 2000, keep: int = 4) -> dict:
    """The ``keep`` largest multipliers at ``steps``, ``2 steps``, ``4 steps`` per period and extrapolated.

    The orbit is found by Newton at ``steps`` (:func:`orbit`) and corrected at each finer level by chord
    steps with the coarser monodromy.  Returns ``{"levels": [m_h, m_h/2, m_h/4], "extrapolated": m,
    "estimate": |last change|, "ratio": observed convergence ratio, "defect": largest orbit defect}``.
    """
    x, base, Phi, defect = orbit(omega, steps)
    levels, defects = [], [defect]
    for s in (steps, 2 * steps, 4 * steps):
        F = OnePeriodMap(omega, s)
        if s != steps:
            for _ in range(3):  # chord steps: the orbit of this level
                r = F.reduced(x, base) - x
                x = x - np.linalg.solve(Phi - np.eye(x.size), r)
            defects.append(float(np.max(np.abs(F.reduced(x, base) - x))))
            Phi = monodromy(F, x, base, 1300.0)
        mu = np.linalg.eigvals(Phi)
        mu = mu[np.argsort(-np.abs(mu))][:keep]
        levels.append(mu if not levels else _match(levels[0], mu))
    m1, m2, m4 = levels
    r1 = (4 * m2 - m1) / 3
    r2 = (4 * m4 - m2) / 3
    ext = (16 * r2 - r1) / 15
    ratio = float(np.max(np.abs(m2 - m1)) / max(float(np.max(np.abs(m4 - m2))), 1e-300))
    return {"levels": levels, "extrapolated": ext, "estimate": float(np.max(np.abs(ext - r2))), "ratio": ratio,
            "defect": max(defects)}
