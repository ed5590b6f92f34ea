"""Constraint-correct linearisation of model files against independent oracles.

* A rigid pendulum whose support is driven vertically (rheonomic constraint, no
  drives): its linearisation about the hanging / upright position is the damped
  Mathieu equation ``J_p th'' + c th' +/- m l (g - a W^2 cos W t) th = 0``.  The
  oracle integrates that scalar equation with scipy (DOP853, rtol 1e-12) and
  reads the transition curves from ``scipy.special.mathieu_a``.
* The gravity restoring term of this model comes entirely from the
  constraint-reaction stiffness ``d(C_q^T lambda)/dq`` (gravity is a constant
  force on the centre of mass), so dropping it must fail the oracle.

Tolerance 1e-6 on the multipliers: the error sources are the central
differences (relative ``eps^(2/3)`` ~ 4e-11 of the stiffness), the orbit
residual (< 1e-6 relative, here ~1e-15 because the orbit is exact) and the
Floquet integration (magnus6, adaptive to rtol 1e-9); the oracle's DOP853 at
rtol 1e-12 is ~1e-10.  1e-6 is a factor > 100 above their sum.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate
import scipy.special

from linearize.analysis import analyze
from linearize.constrained import linearize_orbit
from linearize.periodic_orbit import find_orbit

HERE = Path(__file__).parent
PENDULUM = str(HERE / "models" / "vertical_pendulum.py")

import importlib.util

_spec = importlib.util.spec_from_file_location("vertical_pendulum_constants", PENDULUM)
_pend = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_pend)
m, J, l, g = _pend.MASS, _pend.INERTIA, _pend.LENGTH, _pend.GRAVITY
JP = J + m * l * l


def mathieu_multipliers(omega: float, amplitude: float, damping: float, inverted: bool) -> np.ndarray:
    """Floquet multipliers of J_p th'' + c th' + s m l (g - a W^2 cos W t) th = 0 by scipy (independent)."""
    s = -1.0 if inverted else 1.0

    def rhs(t, y):
        k = s * m * l * (g - amplitude * omega**2 * math.cos(omega * t))
        return [y[1], -(damping * y[1] + k * y[0]) / JP]

    T = 2 * math.pi / omega
    cols = []
    for y0 in ([1.0, 0.0], [0.0, 1.0]):
        sol = scipy.integrate.solve_ivp(rhs, (0, T), y0, method="DOP853", rtol=1e-12, atol=1e-14)
        cols.append(sol.y[:, -1])
    mu = np.linalg.eigvals(np.array(cols).T)
    return mu[np.argsort(-np.abs(mu), kind="stable")]


def _close_sets(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance of a multiplier of ``a`` to its nearest in ``b`` (and vice versa)."""
    d1 = max(float(np.min(np.abs(b - x))) for x in a)
    d2 = max(float(np.min(np.abs(a - x))) for x in b)
    return max(d1, d2)


@pytest.mark.parametrize("inverted, omega, amplitude", [
    (False, 30.0, 0.01),   # hanging (a_M = 0.13, q_M = 0.06)
    (False, 80.0, 0.05),
    (True, 80.0, 0.05),    # Kapitza: upright position stabilised by the vibration
])
def test_vertical_pendulum_is_damped_mathieu(inverted, omega, amplitude):
    res = analyze(PENDULUM, omega, samples=8, method="magnus6", n_steps=None, amplitude=amplitude,
                  inverted=inverted)
    ours = res.floquet.multipliers
    ref = mathieu_multipliers(omega, amplitude, _pend.DAMPING, inverted)
    assert ours.size == 2
    assert _close_sets(ours, ref) < 1e-6
    assert res.orbit.shooting_residual < 1e-2
    if inverted:
        assert res.floquet.spectral_radius < 1.0  # vibration-stabilised


def test_kapitza_case_would_fall_without_vibration():
    """The inverted pendulum at a small support amplitude is unstable (oracle and package agree)."""
    res = analyze(PENDULUM, 80.0, samples=8, method="magnus6", n_steps=None, amplitude=0.01, inverted=True)
    ref = mathieu_multipliers(80.0, 0.01, _pend.DAMPING, True)
    assert _close_sets(res.floquet.multipliers, ref) < 1e-6
    assert res.floquet.spectral_radius > 1.0


def _mathieu_parameters(omega: float, amplitude: float, inverted: bool) -> tuple[float, float]:
    """(a_M, q_M) of y'' + (a - 2 q cos 2 tau) y = 0 with 2 tau = omega t."""
    a_m = (-1.0 if inverted else 1.0) * 4 * m * l * g / (JP * omega**2)
    q_m = 2 * m * l * amplitude / JP
    return a_m, q_m


@pytest.mark.parametrize("side", [0.9, 1.1])
def test_kapitza_stability_boundary_from_mathieu_a(side):
    """Undamped, upright: stable iff a_M > a_0(q_M) (scipy.special.mathieu_a), on both sides of the curve."""
    omega = 80.0
    a_m, _ = _mathieu_parameters(omega, 1.0, True)
    # q* with a_0(q*) = a_M (bisection on scipy's characteristic value; a_0 decreases in q)
    lo, hi = 1e-3, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if scipy.special.mathieu_a(0, mid) > a_m:
            lo = mid
        else:
            hi = mid
    q_star = 0.5 * (lo + hi)
    amplitude = side * q_star * JP / (2 * m * l)
    res = analyze(PENDULUM, omega, samples=8, method="magnus6", n_steps=None, amplitude=amplitude,
                  inverted=True, damping=0.0)
    rho = res.floquet.spectral_radius
    if side > 1:  # beyond the curve: stable (undamped: on the unit circle)
        assert abs(rho - 1.0) < 1e-6
        assert abs(res.floquet.multipliers[0].imag) > 1e-3
    else:
        assert rho > 1.0 + 1e-3


def test_dropping_reaction_stiffness_fails_the_mathieu_oracle():
    """Without d(C_q^T lambda)/dq the pendulum loses its gravity (and vibration) stiffness."""
    from stability import floquet

    orbit = find_orbit(PENDULUM, 80.0, samples=8, verify=False, amplitude=0.05)
    ref = mathieu_multipliers(80.0, 0.05, _pend.DAMPING, False)
    good = floquet(linearize_orbit(orbit), method="magnus6").multipliers
    bad = floquet(linearize_orbit(orbit, reaction_stiffness=False), method="magnus6").multipliers
    assert _close_sets(good, ref) < 1e-6
    assert _close_sets(bad, ref) > 1e-2


# --------------------------------------------------------------------------- double pendulum, two drives
DOUBLE = str(HERE / "models" / "double_pendulum.py")
_dspec = importlib.util.spec_from_file_location("double_pendulum_constants", DOUBLE)
_dp = importlib.util.module_from_spec(_dspec)
_dspec.loader.exec_module(_dp)


def double_pendulum_matrices(t: float, omega: float, kp, kd):
    """Hand-derived linearisation in absolute angles (phi1, phi2) about the driven motion.

    T = 1/2 (J1 + m1 c1^2 + m2 L1^2) phi1'^2 + m2 L1 c2 cos(phi1 - phi2) phi1' phi2' + 1/2 (J2 + m2 c2^2) phi2'^2,
    V = g (m1 c1 + m2 L1) sin phi1 + g m2 c2 sin phi2  (angles from the horizontal, gravity -y).
    M phi'' + h + G = B tau,  h = mu sin(phi1 - phi2) (phi2'^2, -phi1'^2),  mu = m2 L1 c2,
    B = [[1, -1], [0, 1]] (drives: phi1, phi2 - phi1), tau = tau_ff - kp B^T dphi - kd B^T dphi' - joint damping.
    """
    r1, r2 = _dp.motions(omega)
    a, at, att = r1(t)
    b, bt, btt = r2(t)
    p1, p2 = a, a + b
    w1, w2 = at, at + bt
    e1, e2 = att, att + btt
    mu = _dp.M2 * _dp.L1 * _dp.C2
    s, c = math.sin(p1 - p2), math.cos(p1 - p2)
    M = np.array([[_dp.J1 + _dp.M1 * _dp.C1**2 + _dp.M2 * _dp.L1**2, mu * c], [mu * c, _dp.J2 + _dp.M2 * _dp.C2**2]])
    # d(M phi'')/dphi
    dMa = np.array([[-mu * s * e2, mu * s * e2], [-mu * s * e1, mu * s * e1]])
    # dh/dphi, dh/dphi'
    dh = np.array([[mu * c * w2**2, -mu * c * w2**2], [-mu * c * w1**2, mu * c * w1**2]])
    dhv = np.array([[0.0, 2 * mu * s * w2], [-2 * mu * s * w1, 0.0]])
    dG = np.diag([-_dp.G * (_dp.M1 * _dp.C1 + _dp.M2 * _dp.L1) * math.sin(p1), -_dp.G * _dp.M2 * _dp.C2 * math.sin(p2)])
    B = np.array([[1.0, -1.0], [0.0, 1.0]])
    K = dMa + dh + dG + B @ np.diag(kp) @ B.T
    C = dhv + B @ np.diag(np.asarray(kd) + _dp.ALPHA) @ B.T
    return M, C, K


def double_pendulum_multipliers(omega, kp, kd):
    T = 2 * math.pi / omega

    def rhs(t, x):
        M, C, K = double_pendulum_matrices(t, omega, kp, kd)
        y, v = x[:2], x[2:]
        return np.concatenate([v, -np.linalg.solve(M, C @ v + K @ y)])

    cols = [scipy.integrate.solve_ivp(rhs, (0, T), e, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
            for e in np.eye(4)]
    mu = np.linalg.eigvals(np.array(cols).T)
    return mu[np.argsort(-np.abs(mu), kind="stable")]


@pytest.mark.parametrize("kp, kd", [((5.0, 2.0), (0.5, 0.2)), ((0.0, 0.0), (0.0, 0.0))])
def test_double_pendulum_two_drives_against_hand_linearisation(kp, kd):
    """Two drives, revolute joints (reaction stiffness), configuration-dependent inertia coupling."""
    omega = 2 * math.pi
    res = analyze(DOUBLE, omega, kp=kp, kd=kd, samples=32, method="magnus6", n_steps=None)
    ref = double_pendulum_multipliers(omega, kp, kd)
    assert res.drives == ("shoulder", "elbow")
    assert res.linearization.size == 2
    assert _close_sets(res.floquet.multipliers, ref) < 1e-6 * max(1.0, float(np.max(np.abs(ref))))
    # a 5 % change of one gain moves the multipliers far beyond the tolerance (the check can fail)
    wrong = double_pendulum_multipliers(omega, (1.05 * kp[0], kp[1]), kd) if kp[0] else \
        double_pendulum_multipliers(omega, (0.1, 0.0), kd)
    assert _close_sets(res.floquet.multipliers, wrong) > 1e-4


def test_gains_per_drive_and_with_gains_agree():
    """Per-drive gains set at linearisation or later through with_gains give the same system."""
    orbit = find_orbit(DOUBLE, 2 * math.pi, samples=16, verify=False)
    a = linearize_orbit(orbit, kp=(5.0, 2.0), kd=(0.5, 0.2))
    b = linearize_orbit(orbit).with_gains((5.0, 2.0), (0.5, 0.2))
    np.testing.assert_allclose(a.K, b.K, rtol=0, atol=1e-12 * np.max(np.abs(a.K)))
    np.testing.assert_allclose(a.C, b.C, rtol=0, atol=1e-12 * np.max(np.abs(a.C)))
    with pytest.raises(ValueError, match="one value per drive"):
        linearize_orbit(orbit, kp=(1.0, 2.0, 3.0))
