"""The paper's reduced one-mode model of the flexible manipulator (Eqs. 20-25).

The link is described by the hub angle ``q_a`` and one elastic coordinate
``q_e`` (first clamped-free bending mode ``X(x)``).  Linearised about the rigid
fundamental motion ``q_a^R(t) = pi/2 + pi/2 sin(Omega t)``, ``q_e^R = 0``, the
perturbation ``y = [y1, y2] = [q_a - q_a^R, q_e]`` obeys

    M_L y'' + (C_L + K_D) y' + (K_L(t) + K_P) y = h_L(t)        (paper Eqs. 20, 31-32)

with the T-periodic matrices of Eqs. (21)-(24), ``T = 2 pi / Omega``, and the
PD gains of Eq. (27) entering as ``K_P = diag(kp, 0)``, ``K_D = diag(kd, 0)``.

Gravity acts along ``-e_y``; ``q_a = pi/2`` points the link straight up.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq

from mbs_models.parameters import ManipulatorParameters
from stability.periodic import SINGULAR_MASS_RCOND, first_order_matrix

__all__ = [
    "ModeConstants",
    "PAPER_MODE_CONSTANTS",
    "derived_mode_constants",
    "mode_constants",
    "PAPER_LENGTH",
    "FundamentalMotion",
    "ReducedModel",
]


@dataclass(frozen=True)
class ModeConstants:
    """Integrals of the first bending mode ``X(x)`` used by the reduced model.

    Attributes
    ----------
    C1 : float
        ``int_0^l X dx`` (m).
    D1 : float
        ``int_0^l x X dx`` (m^2).
    m11 : float
        ``int_0^l X^2 dx`` (m).
    k11_star : float
        ``int_0^l X''^2 dx`` (1/m^3).
    X1 : float
        Tip value ``X(l)`` (dimensionless).
    source : str
        ``"paper"`` or ``"derived"``.
    """

    C1: float
    D1: float
    m11: float
    k11_star: float
    X1: float
    source: str = "paper"


#: The constants exactly as printed below Eq. (25) of the paper (for l = 0.9 m).
PAPER_MODE_CONSTANTS = ModeConstants(
    C1=-0.704632, D1=-0.460710, m11=0.899850, k11_star=16.955151, X1=-1.9987, source="paper"
)

#: First root of the clamped-free frequency equation cos(b) cosh(b) + 1 = 0 is in this bracket.
_BETA_L_BRACKET = (1.0, 3.0)


def derived_mode_constants(length: float) -> ModeConstants:
    """Mode constants from the clamped-free first mode of a beam of length ``length``.

    Parameters
    ----------
    length : float
        Beam length ``l`` > 0 in m.

    Returns
    -------
    ModeConstants
        With ``source="derived"``.

    Notes
    -----
    Maths: ``X(x) = c [cosh bx - cos bx - s (sinh bx - sin bx)]`` with
    ``b l = 1.8751...`` the first root of ``cos(bl) cosh(bl) + 1 = 0``,
    ``s = (cosh bl + cos bl) / (sinh bl + sin bl)``, normalised so that
    ``int_0^l X^2 dx = l`` and signed so that ``X(l) < 0`` (the paper's sign).
    Then ``X(l) = -2`` and ``k11* = b^4 l``.  The integrals are evaluated by
    adaptive quadrature.  The tip mass is not included in the mode shape (the
    paper's constants are those of the bare clamped-free beam).

    References
    ----------
    .. [1] Meirovitch, L., *Fundamentals of Vibrations*, McGraw-Hill, 2001, Sec. 7.
    """
    if not (math.isfinite(length) and length > 0):
        raise ValueError(f"length must be finite and > 0, got {length!r}")
    bl = brentq(lambda b: math.cos(b) * math.cosh(b) + 1.0, *_BETA_L_BRACKET, xtol=1e-15)
    b = bl / length
    s = (math.cosh(bl) + math.cos(bl)) / (math.sinh(bl) + math.sin(bl))

    def shape(x: float) -> float:
        return math.cosh(b * x) - math.cos(b * x) - s * (math.sinh(b * x) - math.sin(b * x))

    def curvature(x: float) -> float:
        return b * b * (math.cosh(b * x) + math.cos(b * x) - s * (math.sinh(b * x) + math.sin(b * x)))

    norm2 = quad(lambda x: shape(x) ** 2, 0.0, length, epsabs=0, epsrel=1e-13)[0]
    c = -math.sqrt(length / norm2)
    return ModeConstants(
        C1=c * quad(shape, 0.0, length, epsabs=0, epsrel=1e-13)[0],
        D1=c * quad(lambda x: x * shape(x), 0.0, length, epsabs=0, epsrel=1e-13)[0],
        m11=c * c * norm2,
        k11_star=c * c * quad(lambda x: curvature(x) ** 2, 0.0, length, epsabs=0, epsrel=1e-13)[0],
        X1=c * shape(length),
        source="derived",
    )


#: Link length (m) for which the paper prints its mode constants (Table 1).
PAPER_LENGTH = 0.9


def mode_constants(which: Literal["paper", "derived", "auto"], length: float) -> ModeConstants:
    """Return the ``"paper"`` (printed) or ``"derived"`` mode constants.

    ``"auto"`` gives the printed ones for the paper's link length (0.9 m) and
    the derived ones otherwise.

    Raises
    ------
    ValueError
        For an unknown name, or ``"paper"`` with another link length (the
        printed constants are integrals over the 0.9 m link and would be
        silently wrong).
    """
    if which == "auto":
        which = "paper" if abs(length - PAPER_LENGTH) <= 1e-12 * PAPER_LENGTH else "derived"
    if which == "paper":
        if abs(length - PAPER_LENGTH) > 1e-12 * PAPER_LENGTH:
            raise ValueError(
                f"constants='paper' are the paper's printed mode constants for length = {PAPER_LENGTH} m, "
                f"not {length} m; use constants='derived' (or 'auto')"
            )
        return PAPER_MODE_CONSTANTS
    if which == "derived":
        return derived_mode_constants(length)
    raise ValueError(f"constants must be 'paper', 'derived' or 'auto', got {which!r}")


@dataclass(frozen=True)
class FundamentalMotion:
    """Harmonic rigid fundamental motion ``q_a^R(t) = mean + amplitude sin(omega t)``.

    Defaults are the paper's ``pi/2 + pi/2 sin(Omega t)``.
    """

    omega: float
    mean: float = math.pi / 2
    amplitude: float = math.pi / 2

    def __post_init__(self) -> None:
        for name in ("omega", "mean", "amplitude"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v!r}")
        if self.omega <= 0:
            raise ValueError(f"omega must be > 0, got {self.omega!r}")

    @property
    def period(self) -> float:
        """``T = 2 pi / omega``."""
        return 2.0 * math.pi / self.omega

    def angle(self, t):
        """``q_a^R(t)``."""
        return self.mean + self.amplitude * np.sin(self.omega * np.asarray(t, dtype=float))

    def velocity(self, t):
        """``dq_a^R/dt``."""
        return self.amplitude * self.omega * np.cos(self.omega * np.asarray(t, dtype=float))

    def acceleration(self, t):
        """``d^2 q_a^R/dt^2``."""
        return -self.amplitude * self.omega**2 * np.sin(self.omega * np.asarray(t, dtype=float))


#: Mean and amplitude of the paper's fundamental motion (what :attr:`ReducedModel.motion` uses).
_DEFAULT_MOTION = FundamentalMotion(1.0)


@dataclass(frozen=True)
class ReducedModel:
    """The paper's linearised one-mode manipulator with an optional PD controller.

    Parameters
    ----------
    omega : float
        Frequency ``Omega`` of the fundamental motion in rad/s (> 0).
    kp, kd : float
        PD gains of Eq. (27) on the hub angle (>= 0), in N m/rad and N m s/rad.
    params : ManipulatorParameters
        Table 1 data.
    constants : {"auto", "paper", "derived"}
        Which mode constants to use (see :func:`mode_constants`); ``"auto"``
        (default) = the printed ones for the paper's 0.9 m link, derived
        ones for any other length.

    Notes
    -----
    The object is a T-periodic matrix: ``model(t)`` is ``P(t)`` of Eq. (33)
    and ``model.evaluate(times)`` stacks it; ``model.period`` is ``T``.  The
    matrices are those of Eqs. (21)-(24) with ``mu = rho A``,
    ``m_OE = rho A l``, ``m_EG = m_E g``, ``m_OEG = m_OE g`` and
    ``m_EL = m_E l`` (our reading of the paper's abbreviations; it reproduces
    Table 2).

    Examples
    --------
    >>> from stability import floquet
    >>> import math
    >>> res = floquet(ReducedModel(omega=2 * math.pi))
    >>> round(res.spectral_radius, 2)
    13.78
    """

    omega: float = 2.0 * math.pi
    kp: float = 0.0
    kd: float = 0.0
    params: ManipulatorParameters = field(default_factory=ManipulatorParameters)
    constants: str = "auto"

    def __post_init__(self) -> None:
        for name in ("omega", "kp", "kd"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise ValueError(f"{name} must be a real number, got {v!r}")
            if not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.omega <= 0:
            raise ValueError(f"omega must be > 0, got {self.omega!r}")
        if self.kp < 0:
            raise ValueError(f"kp must be >= 0, got {self.kp!r}")
        if self.kd < 0:
            raise ValueError(f"kd must be >= 0, got {self.kd!r}")
        if not isinstance(self.params, ManipulatorParameters):
            raise ValueError("params must be a ManipulatorParameters instance")
        mc = mode_constants(self.constants, self.params.length)
        object.__setattr__(self, "_mc", mc)
        object.__setattr__(self, "_M", self._mass_matrix(mc))
        M = self._M  # type: ignore[attr-defined]
        if not np.all(np.isfinite(M)) or np.linalg.cond(M) * SINGULAR_MASS_RCOND > 1.0:
            raise ValueError(f"mass matrix M_L is singular or not finite: {M.tolist()}")
        object.__setattr__(self, "_Minv", np.linalg.inv(M))
        object.__setattr__(self, "_affine", self._affine_parts())
        # the three parts as the rows of one (3, 16) matrix: evaluate() is one product
        object.__setattr__(self, "_affine_rows", np.stack(self._affine).reshape(3, -1))

    # ---------------------------------------------------------------- basics
    @property
    def period(self) -> float:
        """``T = 2 pi / Omega``."""
        return 2.0 * math.pi / self.omega

    @property
    def motion(self) -> FundamentalMotion:
        """The fundamental motion ``q_a^R``."""
        return FundamentalMotion(self.omega)

    @property
    def mode(self) -> ModeConstants:
        """The mode constants in use."""
        return self._mc  # type: ignore[attr-defined]

    def with_gains(self, kp: float, kd: float) -> "ReducedModel":
        """A copy with other PD gains (cheap: mode constants are reused)."""
        return ReducedModel(self.omega, kp, kd, self.params, self.constants)

    def _mass_matrix(self, mc: ModeConstants) -> np.ndarray:
        p = self.params
        mu, l, mE = p.mass_per_length, p.length, p.tip_mass
        m11 = p.hub_inertia + mE * l**2 + p.link_mass * l**2 / 3.0
        m12 = mu * mc.D1 + mE * l * mc.X1
        m22 = mE * mc.X1**2 + mu * mc.m11
        return np.array([[m11, m12], [m12, m22]])

    # ---------------------------------------------------------------- matrices
    def mass(self, t) -> np.ndarray:
        """``M_L`` (Eq. 21), constant in time; shape ``(2, 2)`` or ``(m, 2, 2)``."""
        t = np.asarray(t, dtype=float)
        return np.broadcast_to(self._M, t.shape + (2, 2)).copy()

    def damping(self, t) -> np.ndarray:
        """``C_L + K_D`` (Eqs. 22, 32)."""
        t = np.asarray(t, dtype=float)
        C = np.zeros(t.shape + (2, 2))
        C[..., 0, 0] = self.params.joint_damping + self.kd
        return C

    def stiffness(self, t) -> np.ndarray:
        """``K_L(t) + K_P`` (Eqs. 23, 32)."""
        p, mc = self.params, self.mode
        t = np.asarray(t, dtype=float)
        q = self.motion.angle(t)
        qd = self.motion.velocity(t)
        s = np.sin(q)
        mEg = p.tip_mass * p.gravity
        k11 = -p.length * s * mEg - p.link_mass * p.gravity * p.length * s / 2.0
        k12 = -mEg * mc.X1 * s - p.mass_per_length * p.gravity * s * mc.C1
        k22 = (
            -p.tip_mass * qd**2 * mc.X1**2
            - p.mass_per_length * qd**2 * mc.m11
            + p.bending_stiffness * mc.k11_star
        )
        K = np.empty(t.shape + (2, 2))
        K[..., 0, 0] = k11 + self.kp
        K[..., 0, 1] = k12
        K[..., 1, 0] = k12
        K[..., 1, 1] = k22
        return K

    def forcing(self, t) -> np.ndarray:
        """``h_L(t)`` (Eq. 24); shape ``(2,)`` or ``(m, 2)``."""
        p, mc = self.params, self.mode
        t = np.asarray(t, dtype=float)
        q = self.motion.angle(t)
        qdd = self.motion.acceleration(t)
        c = np.cos(q)
        h = np.zeros(t.shape + (2,))
        h[..., 1] = (
            -p.tip_mass * p.gravity * mc.X1 * c
            - p.mass_per_length * p.gravity * c * mc.C1
            - p.tip_mass * p.length * mc.X1 * qdd
            - p.mass_per_length * mc.D1 * qdd
        )
        return h

    # ---------------------------------------------------------------- first order
    def _affine_parts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(P_c, P_s, P_w)`` with ``P(t) = P_c + sin(q_a^R) P_s + (dq_a^R/dt)^2 P_w``.

        ``K(t)`` of Eq. (23) is affine in ``sin q_a^R(t)`` and ``(dq_a^R/dt)^2``
        and ``M``, ``C`` are constant, so ``P`` is affine in the same two
        functions; the three constant matrices come from
        :func:`~stability.periodic.first_order_matrix` (the one place ``P`` is
        built), evaluated at ``(sin, qdot^2) = (0, 0), (1, 0), (0, 1)``.
        """
        p, mc, Minv = self.params, self.mode, self._Minv  # type: ignore[attr-defined]
        M, C, Z = self._M, self.damping(0.0), np.zeros((2, 2))  # type: ignore[attr-defined]
        mEg = p.tip_mass * p.gravity
        K0 = np.array([[self.kp, 0.0], [0.0, p.bending_stiffness * mc.k11_star]])
        k11s = -p.length * mEg - p.link_mass * p.gravity * p.length / 2.0
        k12s = -mEg * mc.X1 - p.mass_per_length * p.gravity * mc.C1
        Ks = np.array([[k11s, k12s], [k12s, 0.0]])
        Kw = np.array([[0.0, 0.0], [0.0, -p.tip_mass * mc.X1**2 - p.mass_per_length * mc.m11]])
        Pc = first_order_matrix(M, C, K0, mass_inverse=Minv)
        Pz = first_order_matrix(M, Z, Z, mass_inverse=Minv)
        Ps = first_order_matrix(M, Z, Ks, mass_inverse=Minv) - Pz
        Pw = first_order_matrix(M, Z, Kw, mass_inverse=Minv) - Pz
        return Pc, Ps, Pw

    def evaluate(self, times) -> np.ndarray:
        """``P(t)`` of Eq. (33) stacked over ``times``: shape ``(m, 4, 4)``.

        Evaluated as ``P_c + sin(q_a^R) P_s + (dq_a^R/dt)^2 P_w`` (see
        :meth:`_affine_parts`; identical to ``first_order_matrix(mass,
        damping, stiffness)`` up to rounding, and ~10x cheaper).
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        motion = _DEFAULT_MOTION  # q_a^R = mean + amplitude sin(omega t), the paper's pi/2 + pi/2 sin
        sin_wt = np.sin(self.omega * times)
        coef = np.empty(times.shape + (3,))
        coef[..., 0] = 1.0
        coef[..., 1] = np.sin(motion.mean + motion.amplitude * sin_wt)
        # (dq_a^R/dt)^2 = (amplitude omega cos wt)^2, with cos^2 = 1 - sin^2 (one transcendental less)
        coef[..., 2] = (motion.amplitude * self.omega) ** 2 * (1.0 - sin_wt * sin_wt)
        n = self._affine[0].shape[0]  # type: ignore[attr-defined]
        return (coef @ self._affine_rows).reshape(times.shape + (n, n))  # type: ignore[attr-defined]

    def __call__(self, t: float) -> np.ndarray:
        """``P(t)`` at one time: the formula of :meth:`evaluate` in scalar arithmetic (an ODE
        right-hand side calls this ~10^5 times per transient; ~10x cheaper than ``evaluate``)."""
        Pc, Ps, Pw = self._affine  # type: ignore[attr-defined]
        motion = _DEFAULT_MOTION
        wt = self.omega * float(t)
        s = math.sin(motion.mean + motion.amplitude * math.sin(wt))
        w = (motion.amplitude * self.omega * math.cos(wt)) ** 2
        return Pc + s * Ps + w * Pw

    def forcing_first_order(self, t) -> np.ndarray:
        """``f(t) = [0, M^-1 h_L]`` of Eq. (5)."""
        h = self.forcing(t)
        f = np.zeros(h.shape[:-1] + (4,))
        f[..., 2:] = h @ self._Minv.T  # type: ignore[attr-defined]
        return f

    def trace_integral(self) -> float:
        """``int_0^T tr P dt = -T tr(M^-1 (C_L + K_D))`` in closed form (M and C are constant)."""
        # C_L + K_D has only its (0, 0) entry: tr(M^-1 C) = (M^-1)_00 C_00
        return -self.period * float(self._Minv[0, 0] * self.damping(0.0)[0, 0])  # type: ignore[attr-defined]
