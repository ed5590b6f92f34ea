"""Hand-written reference for a rigid rotor carried by a turning hub (independent of the package).

The rotor (mass ``m``, principal inertia ``J = diag(J_p, J_t, J_t)`` about its centre) hangs on
``len(PADS)`` isotropic spring-dampers (stiffness ``k``, damping ``c``) between body points ``p_i`` and
the hub points ``R_h(t) p_i`` of a hub turning about ``x`` at the constant speed ``W``
(``R_h = R_x(W t)``), under gravity ``-g e_y``.  Newton-Euler equations, rotation matrix ``R`` and body
angular velocity ``w``::

    m x'' = sum_i F_i - m g e_y,        J w' + w x J w = sum_i p_i x R^T F_i,        R' = R [w]x,
    F_i = -k (x + R p_i - R_h p_i) - c (x' + R (w x p_i) - W e_x x R_h p_i).

The orbit is found by shooting (Newton on the 12 minimal coordinates ``x, theta, x', w`` with
``R = R_h(0) expm([theta]x)``) and the monodromy matrix in those coordinates by complex-step
differentiation of the DOP853 flow (``rtol = 1e-12``): the derivative of the discrete flow, i.e. the
variational equation integrated with the same steps, exact to rounding (no difference step).
"""
from __future__ import annotations

import functools

import numpy as np
import scipy.integrate
from scipy.spatial.transform import Rotation

#: The model file's data (tests/models/hub_rotor.py), repeated on purpose.
ROTOR = {"mass": 2.0, "j_polar": 0.01, "j_transverse": 0.05, "stiffness": 4.0e3, "damping": 2.0}
PADS = np.array([(0.2, 0.05, 0.0), (0.2, -0.05, 0.0), (-0.2, 0.0, 0.05), (-0.2, 0.0, -0.05)])
#: DOP853 tolerance (measured: 1e-12 leaves 5e-9 in the multipliers, 1e-13 5e-10 from the package)
RTOL = 1e-13
#: complex step (the derivative is exact to rounding for any small step: no subtraction)
STEP = 1e-30


def _skew(w):
    """``[w]x`` of the columns of ``w`` (shape ``(3, c)``): shape ``(c, 3, 3)``."""
    z = np.zeros_like(w[0])
    return np.stack([np.stack([z, -w[2], w[1]], -1), np.stack([w[2], z, -w[0]], -1),
                     np.stack([-w[1], w[0], z], -1)], 1)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _rhs(t, y, W, g, cols):
    """Right-hand side for ``cols`` copies of the state side by side (complex-step columns)."""
    m, jp, jt, k, c = (ROTOR[key] for key in ("mass", "j_polar", "j_transverse", "stiffness", "damping"))
    Y = y.reshape(18, cols)
    x, v, w, R = Y[0:3], Y[3:6], Y[6:9], Y[9:18].reshape(3, 3, cols)
    Rh = _rx(W * t)
    J = np.array([jp, jt, jt])[:, None]
    F = np.zeros_like(x)
    tau = np.zeros_like(x)
    for p in PADS:
        h = Rh @ p
        hd = W * np.cross([1.0, 0.0, 0.0], h)
        wxp = np.cross(w, p[:, None], axis=0)
        Fi = -k * (x + np.einsum("ijc,j->ic", R, p) - h[:, None]) - c * (v + np.einsum("ijc,jc->ic", R, wxp)
                                                                         - hd[:, None])
        F = F + Fi
        tau = tau + np.cross(p[:, None], np.einsum("jic,jc->ic", R, Fi), axis=0)
    F[1] = F[1] - m * g
    dw = (tau - np.cross(w, J * w, axis=0)) / J
    dR = np.einsum("ijc,cjk->ikc", R, _skew(w))
    return np.concatenate([v, F / m, dw, dR.reshape(9, cols)]).ravel()


def _flow(z, W, g, perturbations=None):
    """States after one period (shape ``(18, c)``) from minimal coordinates ``z = (x, theta, x', w)``,
    one column per complex-step perturbation of those coordinates (columns of ``perturbations``)."""
    T = 2 * np.pi / W
    R0 = Rotation.from_rotvec(z[3:6]).as_matrix()
    d = np.zeros((12, 1)) if perturbations is None else perturbations
    cols = d.shape[1]
    x, v, w = z[0:3, None] + d[0:3], z[6:9, None] + d[6:9], z[9:12, None] + d[9:12]
    R = np.einsum("ij,cjk->ikc", R0, np.eye(3)[None] + _skew(d[3:6]))  # expm to first order: exact here
    y0 = np.concatenate([x, v, w, R.reshape(9, cols)]).ravel()
    sol = scipy.integrate.solve_ivp(_rhs, (0.0, T), y0, method="DOP853", rtol=RTOL, atol=1e-14, args=(W, g, cols))
    return sol.y[:, -1].reshape(18, cols), R0


def _minimal(YT, R0, linear):
    """Minimal coordinates of the end states (rotation: ``R0^T R(T)``, its rotation vector or, for a
    complex step, its skew part, which is linear in the step)."""
    E = np.einsum("ji,jkc->ikc", R0, YT[9:18].reshape(3, 3, -1))
    if linear:
        S = 0.5 * (E - np.transpose(E, (1, 0, 2)))
        th = np.stack([S[2, 1], S[0, 2], S[1, 0]])
    else:
        th = Rotation.from_matrix(np.transpose(E, (2, 0, 1)).real).as_rotvec().T
    return np.concatenate([YT[0:3], th, YT[3:6], YT[6:9]])


def _defect(z, W, g):
    YT, R0 = _flow(z, W, g)
    return _minimal(YT, R0, False)[:, 0]


def _jacobian(z, W, g):
    """d flow / d z (rotation: body-frame increments at both ends), by complex step."""
    YT, R0 = _flow(z, W, g, 1j * STEP * np.eye(12))
    return _minimal(YT, R0, True).imag / STEP


def orbit(W: float, g: float = 0.0, iterations: int = 12) -> np.ndarray:
    """Minimal coordinates at ``t = 0`` of the T-periodic orbit (``R(0) = expm([theta]x)``)."""
    z = np.zeros(12)
    z[9] = W
    for _ in range(iterations):
        fz = _defect(z, W, g)
        rot = Rotation.from_rotvec(z[3:6]).as_matrix()
        res = fz - z
        res[3:6] = fz[3:6]  # R0^T R(T) = expm([e]x): the rotation defect itself
        if np.max(np.abs(res)) < 1e-13:
            break
        Phi = _jacobian(z, W, g)
        A = Phi - np.eye(12)
        A[3:6, 3:6] = Phi[3:6, 3:6] - np.eye(3)  # body-frame rotation increments on both sides
        dz = np.linalg.solve(A, -res)
        z = z + dz
        z[3:6] = (Rotation.from_matrix(rot) * Rotation.from_rotvec(dz[3:6])).as_rotvec()
    return z


def monodromy(W: float, g: float = 0.0) -> np.ndarray:
    return _jacobian(orbit(W, g), W, g)


@functools.lru_cache(maxsize=8)
def _multipliers(W: float, g: float) -> tuple:
    return tuple(np.linalg.eigvals(monodromy(W, g)))


def multipliers(W: float, g: float = 0.0) -> np.ndarray:
    """Multipliers at shaft speed ``W`` and gravity ``g`` (cached: ~3 s CPU each)."""
    return np.array(_multipliers(float(W), float(g)))
