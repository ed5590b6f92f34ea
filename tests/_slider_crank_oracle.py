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


def _richardson(levels: list) -> dict:
    """Two Richardson passes over the h, h/2, h/4 levels of a second-order rule (h^2, then h^4), the
    change of the last pass as the estimate, and the observed ratio of the level changes (4 at order 2)."""
    m1, m2, m4 = levels
    r1 = (4 * m2 - m1) / 3
    r2 = (4 * m4 - m2) / 3
    ext = (16 * r2 - r1) / 15
    ratio = float(np.max(np.abs(m2 - m1)) / max(float(np.max(np.abs(m4 - m2))), 1e-300))
    return {"levels": levels, "extrapolated": ext, "estimate": float(np.max(np.abs(ext - r2))), "ratio": ratio}


def multipliers(omega: float, steps: int = 2000, keep: int = 4) -> dict:
    """The ``keep`` largest multipliers at ``steps``, ``2 steps``, ``4 steps`` per period and extrapolated.

    The orbit is found by Newton at ``steps`` (:func:`orbit`) and corrected at each finer level by chord
    steps with the coarser monodromy.  Returns ``{"levels": [m_h, m_h/2, m_h/4], "extrapolated": m,
    "estimate": |last change|, "ratio": observed convergence ratio, "defect": largest orbit defect}``.
    """
    x, base, Phi, defect = orbit(omega, steps)
    levels, defects, orbits = [], [defect], []
    for s in (steps, 2 * steps, 4 * steps):
        F = OnePeriodMap(omega, s)
        if s != steps:
            for _ in range(3):  # chord steps: the orbit of this level
                r = F.reduced(x, base) - x
                x = x - np.linalg.solve(Phi - np.eye(x.size), r)
            defects.append(float(np.max(np.abs(F.reduced(x, base) - x))))
            Phi = monodromy(F, x, base, 1300.0)
        orbits.append((x.copy(), base))
        mu = np.linalg.eigvals(Phi)
        mu = mu[np.argsort(-np.abs(mu))][:keep]
        levels.append(mu if not levels else _match(levels[0], mu))
    return {**_richardson(levels), "defect": max(defects), "steps": steps, "orbits": orbits}


# ----------------------------------------------------------------------------------------------------------
# The drive form under feed-forward + PD: the crank released, tau = tau_ff(t) - kp (theta - W t) - kd (theta' - W)
# ----------------------------------------------------------------------------------------------------------
#: Free coordinates of the closed loop: the crank angle joins; the pin node's position (3, 4) follows it.
FREE_DRIVE = np.array([2, 5, 6, 7, 8, 9, 10, 11, 13, 14])
#: Harmonics kept of the recorded feed-forward torque (its samples' trigonometric interpolant).
FEEDFORWARD_HARMONICS = 48


def feedforward(omega: float, steps: int, x: np.ndarray, base: tuple) -> np.ndarray:
    """Fourier coefficients (``numpy.fft.rfft`` / N, first :data:`FEEDFORWARD_HARMONICS`) of the torque that
    holds the crank on ``omega t`` along the constant-speed orbit ``x``: minus the Lagrange multiplier of the
    rheonomic crank constraint (its equation is ``theta - omega t = 0``, so its generalised force on
    ``theta`` is ``-lambda``), recorded after every step of one period."""
    import exudyn as exu

    F = OnePeriodMap(omega, steps)
    idx = F.mbs.GetObjectNumber("crank speed")
    record: list = []

    def post_step(mbs, t):
        record.append((t, float(mbs.GetObjectOutput(idx, exu.OutputVariableType.Force))))
        return True

    F.mbs.SetPostStepUserFunction(post_step)
    q, v = base[0].copy(), base[1].copy()
    q[FREE], v[FREE] = x[:FREE.size], x[FREE.size:]
    F(q, v)
    t, lam = np.array(record).T
    # the last sample is t = T (= t = 0 of the next period): N equispaced samples 0 .. T - h, rolled
    samples = np.roll(-lam[-steps:], 1)
    return np.fft.rfft(samples)[:FEEDFORWARD_HARMONICS] / steps


def _trig(coef: np.ndarray, omega: float, t: float) -> float:
    k = np.arange(coef.size)
    w = np.where(k == 0, 1.0, 2.0)
    return float(np.sum(w * (coef.real * np.cos(k * omega * t) - coef.imag * np.sin(k * omega * t))))


class ClosedLoopMap(OnePeriodMap):
    """One period of the drive form released under feed-forward + PD (a ``CoordinateSpringDamper`` on the crank
    angle whose spring-force user function is ``kp (theta - W t) + kd (theta' - W) - tau_ff(t)``)."""

    def __init__(self, omega: float, steps: int, kp: float, kd: float, coef: np.ndarray):
        import exudyn as exu
        from exudyn.itemInterface import CoordinateSpringDamper, MarkerNodeCoordinate, NodePointGround

        from mbs_models.builtin.slider_crank import DEFAULTS, build

        self.omega, self.T = float(omega), 2 * math.pi / float(omega)
        self.sc = exu.SystemContainer()
        self.mbs = self.sc.AddSystem()
        drives = build(self.mbs, omega, form="drive", elements=2)
        m0, m1 = drives[0]["markers"]
        W = self.omega
        last = [None, 0.0]  # tau_ff at the last time asked (Newton iterations of a step share it)

        def force(mbs, t, item, u, v, k, d, offset):
            if t != last[0]:
                last[0], last[1] = t, _trig(coef, W, t)
            return kp * (u - W * t) + kd * (v - W) - last[1]

        self.mbs.AddObject(CoordinateSpringDamper(markerNumbers=[m0, m1], stiffness=kp, damping=kd,
                                                  springForceUserFunction=force))
        self.mbs.Assemble()
        self.settings = _settings(self.T, steps)
        self.r = DEFAULTS["crank"]
        sd = self.mbs.systemData
        ini = exu.ConfigurationType.Initial
        self.q_file = np.array(sd.GetODE2Coordinates(configuration=ini))
        self.v_file = np.array(sd.GetODE2Coordinates_t(configuration=ini))
        self._exu = exu

    def reduced(self, x: np.ndarray, base: tuple) -> np.ndarray:
        n = FREE_DRIVE.size
        q, v = base[0].copy(), base[1].copy()
        q[FREE_DRIVE], v[FREE_DRIVE] = x[:n], x[n:]
        th, w = q[2], v[2]  # the pin node's position follows the crank exactly (displacement from (r, 0))
        q[3], q[4] = self.r * math.cos(th) - self.r, self.r * math.sin(th)
        v[3], v[4] = -self.r * math.sin(th) * w, self.r * math.cos(th) * w
        qT, vT = self(q, v)
        return np.concatenate([qT[FREE_DRIVE], vT[FREE_DRIVE]])


def _monodromy_drive(F, x, base, rate_scale):
    n = x.size
    h = np.where(np.arange(n) < FREE_DRIVE.size, EPS, EPS * rate_scale)
    cols = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = h[j]
        cols.append((F.reduced(x + e, base) - F.reduced(x - e, base)) / (2 * h[j]))
    return np.array(cols).T


def closed_loop_multipliers(constant: dict, omega: float, kp: float, kd: float, keep: int = 4) -> dict:
    """As :func:`multipliers`, for the drive form under feed-forward + PD, at the step levels of ``constant``
    (a :func:`multipliers` result): the feed-forward of each level is recorded along that level's own
    constant-speed orbit, the closed loop's periodic orbit found by chord steps from it.  Adds
    ``"orbit_gap"``: the closed loop's orbit against the constant-speed one at the finest level (max norm
    over the free positions and rates): the feed-forward is the recorded reaction of the trapezoidal rule,
    truncated to :data:`FEEDFORWARD_HARMONICS`, so the two orbits differ by what that misses."""
    steps = constant["steps"]
    levels, defects = [], []
    Phi = None
    gap = math.nan
    for s, (x_c, base_c) in zip((steps, 2 * steps, 4 * steps), constant["orbits"]):
        coef = feedforward(omega, s, x_c, base_c)
        F = ClosedLoopMap(omega, s, kp, kd, coef)
        q, v = base_c[0].copy(), base_c[1].copy()
        q[FREE], v[FREE] = x_c[:FREE.size], x_c[FREE.size:]
        base = (q, v)
        x0 = np.concatenate([q[FREE_DRIVE], v[FREE_DRIVE]])
        x = x0.copy()
        if Phi is None:
            Phi = _monodromy_drive(F, x, base, 1300.0)
        for _ in range(3):  # the closed loop's own periodic orbit (chord steps from the constant-speed one)
            r = F.reduced(x, base) - x
            x = x - np.linalg.solve(Phi - np.eye(x.size), r)
        defects.append(float(np.max(np.abs(F.reduced(x, base) - x))))
        gap = float(np.max(np.abs(x - x0)))
        Phi = _monodromy_drive(F, x, base, 1300.0)
        mu = np.linalg.eigvals(Phi)
        mu = mu[np.argsort(-np.abs(mu))][:keep]
        levels.append(mu if not levels else _match(levels[0], mu))
    return {**_richardson(levels), "defect": max(defects), "orbit_gap": gap}
