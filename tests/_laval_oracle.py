"""Closed-form reference of the anisotropic Laval (Jeffcott) rotor, derived by hand (independent of the package).

Inertial frame: ``m u'' + c u' + R(W t) diag(k_xi, k_eta) R(W t)^T u = 0`` (the homogeneous part; gravity does
not enter the linearisation).  With ``u = R(W t) xi`` (shaft-fixed coordinates), ``R' = W J R``, ``J = [[0, -1],
[1, 0]]``, ``J^2 = -I``:

    m (xi'' + 2 W J xi' - W^2 xi) + c (xi' + W J xi) + diag(k_xi, k_eta) xi = 0,

constant coefficients.  State ``x = (u, u')`` and ``s = (xi, xi')`` are related by ``x = S(t) s`` with
``S = [[R, 0], [W J R, R]]``; ``R(2 pi) = I``, so over one turn ``T = 2 pi / W`` the monodromy matrix is
``S(0) expm(A T) S(0)^-1``: the multipliers are ``exp(lambda_r T)`` exactly.  A rotating-frame mode
``xi = xi_hat exp(lambda_r t)`` is seen in the inertial frame at ``lambda_r + i W`` with amplitude
``P_+ xi_hat`` and at ``lambda_r - i W`` with ``P_- xi_hat`` (``R = e^{iWt} P_+ + e^{-iWt} P_-``,
``P_+- = (I -+ i J) / 2``).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

J = np.array([[0.0, -1.0], [1.0, 0.0]])
P_PLUS = 0.5 * (np.eye(2) - 1j * J)
P_MINUS = 0.5 * (np.eye(2) + 1j * J)
#: The built-in's defaults (mbs_models/builtin/laval_rotor.py), repeated here on purpose.
ROTOR = {"mass": 2.0, "stiffness_xi": 2.0e4, "stiffness_eta": 2.6e4, "damping": 2.0}


def rotating_matrix(W: float, mass=2.0, stiffness_xi=2.0e4, stiffness_eta=2.6e4, damping=2.0) -> np.ndarray:
    """First-order matrix of the shaft-fixed equations (constant)."""
    m, c = mass, damping
    K = np.diag([stiffness_xi, stiffness_eta])
    return np.block([[np.zeros((2, 2)), np.eye(2)],
                     [-(K - m * W**2 * np.eye(2) + c * W * J) / m, -(2 * m * W * J + c * np.eye(2)) / m]])


def monodromy(W: float, **rotor) -> np.ndarray:
    """Exact inertial-frame monodromy matrix over ``T = 2 pi / W``."""
    S0 = np.block([[np.eye(2), np.zeros((2, 2))], [W * J, np.eye(2)]])
    return S0 @ scipy.linalg.expm(rotating_matrix(W, **rotor) * 2 * np.pi / W) @ np.linalg.inv(S0)


def multipliers(W: float, **rotor) -> np.ndarray:
    return np.exp(np.linalg.eigvals(rotating_matrix(W, **rotor)) * 2 * np.pi / W)


def principal_modes(W: float, **rotor) -> list:
    """Per rotating-frame eigenvalue with ``Im >= 0``: ``(frequency, damping ratio, share)`` of the inertial
    harmonic with the larger amplitude (``lambda_r +- i W``), the rule of :mod:`stability.campbell`."""
    lam, V = np.linalg.eig(rotating_matrix(W, **rotor))
    out = []
    for l, v in zip(lam, V.T):
        if l.imag < -1e-9 * abs(l):
            continue
        a, b = np.linalg.norm(P_PLUS @ v[:2]) ** 2, np.linalg.norm(P_MINUS @ v[:2]) ** 2
        rep = l + 1j * W if a >= b else l - 1j * W
        if rep.imag < 0:
            rep = np.conj(rep)
        out.append((float(rep.imag), float(-rep.real / abs(rep)), float(max(a, b) / (a + b))))
    return sorted(out)
