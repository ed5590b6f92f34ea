"""Hand-derived equations of the hinged blade of tests/models/hinged_blade.py (independent of the package).

Generalised coordinates: hub angle ``theta`` (absolute) and blade angle ``beta`` relative to the hub;
blade centre of mass at ``R e(theta) + s e(theta + beta)``.  Lagrange's equations (``J_p = J + m s^2``)::

    M11 theta'' + M12 beta'' - 2 m R s sin(beta) theta' beta' - m R s sin(beta) beta'^2
        + m g (R cos(theta) + s cos(theta + beta)) = tau
    M12 theta'' + M22 beta'' + m R s sin(beta) theta'^2 + m g s cos(theta + beta) + k beta + c beta' = 0

    M11 = J_hub + J + m (R^2 + s^2 + 2 R s cos(beta)),  M12 = J_p + m R s cos(beta),  M22 = J_p.

With the hub held at ``theta = Omega t`` the second equation is the blade's own::

    J_p beta'' + c beta' + m R s Omega^2 sin(beta) + m g s cos(Omega t + beta) + k beta = 0

and its variational equation about an orbit ``beta0(t)``::

    J_p d'' + c d' + (m R s Omega^2 cos(beta0) - m g s sin(Omega t + beta0) + k) d = 0.

With the hub released under feed-forward + PD, ``tau = tau_ff(t) - kp (theta - Omega t) - kd (theta' - Omega)``,
``tau_ff`` the torque that keeps the hub on ``Omega t`` along the orbit.
"""
import importlib.util
import math
from pathlib import Path

import numpy as np
import scipy.integrate
import scipy.optimize

MODEL = Path(__file__).with_name("models") / "hinged_blade.py"
_spec = importlib.util.spec_from_file_location("hinged_blade_constants", MODEL)
hb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(hb)

RTOL, ATOL = 1e-12, 1e-14
m, J, R, s, k, c, g, Jh = hb.MASS, hb.INERTIA, hb.RADIUS, hb.ARM, hb.STIFFNESS, hb.DAMPING, hb.GRAVITY, hb.J_HUB
Jp = J + m * s * s


def _solve(fun, T, y0):
    sol = scipy.integrate.solve_ivp(fun, (0.0, T), y0, method="DOP853", rtol=RTOL, atol=ATOL)
    assert sol.success
    return sol.y[:, -1]


def blade_orbit(omega, centrifugal_sign=1.0):
    """``(beta0(0), beta0'(0))`` of the T-periodic blade motion with the hub held (Newton on the
    period map)."""
    T = 2 * math.pi / omega

    def f(t, y):
        b, bd = y
        return [bd, -(c * bd + centrifugal_sign * m * R * s * omega**2 * math.sin(b)
                      + m * g * s * math.cos(omega * t + b) + k * b) / Jp]

    y0 = scipy.optimize.fsolve(lambda y: _solve(f, T, y) - y, [0.0, 0.0], xtol=1e-13)
    return y0, f


def blade_multipliers(omega, centrifugal_sign=1.0):
    """Multipliers of the hand-derived variational equation of the blade (hub held)."""
    T = 2 * math.pi / omega
    y0, f = blade_orbit(omega, centrifugal_sign)

    def aug(t, y):
        b, bd = y[0], y[1]
        stiff = centrifugal_sign * m * R * s * omega**2 * math.cos(b) - m * g * s * math.sin(omega * t + b) + k
        X = y[2:].reshape(2, 2)
        A = np.array([[0.0, 1.0], [-stiff / Jp, -c / Jp]])
        return np.concatenate([f(t, y[:2]), (A @ X).ravel()])

    yT = _solve(aug, T, np.concatenate([y0, np.eye(2).ravel()]))
    return np.linalg.eigvals(yT[2:].reshape(2, 2))


def _hub_blade_rhs(x, tau):
    """``x = (theta, beta, theta', beta')`` -> ``x'`` of Lagrange's equations (complex-safe)."""
    th, b, thd, bd = x
    cb, sb = np.cos(b), np.sin(b)
    M11 = Jh + J + m * (R * R + s * s + 2 * R * s * cb)
    M12 = Jp + m * R * s * cb
    r1 = tau + 2 * m * R * s * sb * thd * bd + m * R * s * sb * bd**2 - m * g * (R * np.cos(th) + s * np.cos(th + b))
    r2 = -m * R * s * sb * thd**2 - m * g * s * np.cos(th + b) - k * b - c * bd
    det = M11 * Jp - M12 * M12
    return np.array([thd, bd, (Jp * r1 - M12 * r2) / det, (M11 * r2 - M12 * r1) / det])


def hub_blade_multipliers(omega, kp, kd, turns=1):
    """Multipliers of the hub + blade with the hub released under feed-forward + PD about the orbit
    ``theta = turns Omega t``, ``beta0(t)`` (variational equation by complex-step differentiation of
    the hand-derived right-hand side: exact to rounding)."""
    T = 2 * math.pi / omega
    w = turns * omega
    y0, f = blade_orbit(w) if turns == 1 else blade_orbit(w)  # the blade sees the hub's own speed

    def tau_ff(t, b, bd):
        # the torque that keeps theta'' = 0 at theta = w t: solve the two equations for (tau, beta'')
        cb, sb = math.cos(b), math.sin(b)
        M12 = Jp + m * R * s * cb
        r2 = -m * R * s * sb * w**2 - m * g * s * math.cos(w * t + b) - k * b - c * bd
        bdd = r2 / Jp
        return (M12 * bdd - 2 * m * R * s * sb * w * bd - m * R * s * sb * bd**2
                + m * g * (R * math.cos(w * t) + s * math.cos(w * t + b)))

    def closed(t, x, base):
        th, b, thd, bd = x
        return _hub_blade_rhs(x, base - kp * (th - w * t) - kd * (thd - w))

    def aug(t, y):
        b, bd = y[0], y[1]
        base = tau_ff(t, b, bd)
        x0 = np.array([w * t, b, w, bd])
        h = 1e-30
        A = np.empty((4, 4))
        for j in range(4):
            e = np.zeros(4, dtype=complex)
            e[j] = 1j * h
            A[:, j] = closed(t, x0 + e, base).imag / h
        X = y[2:].reshape(4, 4)
        return np.concatenate([f(t, y[:2]), (A @ X).ravel()])

    yT = _solve(aug, T, np.concatenate([y0, np.eye(4).ravel()]))
    return np.linalg.eigvals(yT[2:].reshape(4, 4))
