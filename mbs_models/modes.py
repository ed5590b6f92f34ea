"""Natural frequencies of the flexible link: Exudyn's matrices and Euler-Bernoulli theory.

Two boundary conditions at the hub, gravity off, link straight:

``"clamped"``
    hub held fixed: a clamped-free beam with the tip mass ``m_E``.
``"pinned"``
    hub free to rotate about O with inertia ``J1`` (the beam clamped to the
    hub): one rigid-body mode at 0 Hz, then the flexible modes.

:func:`exudyn_frequencies` projects Exudyn's mass matrix and its own
stiffness Jacobian ``K = -df/dq`` (at the undeformed, unloaded reference) of the
built-in model file ``single-link`` onto the null space of its constraints and
solves the generalised eigenproblem.  :func:`analytic_frequencies`
solves the Euler-Bernoulli frequency equation with tip mass (and hub
inertia) by bracketing and Brent's method.

Maths
-----
With ``W(xi) = a cos(b xi) + b_ sin(b xi) + c cosh(b xi) + d sinh(b xi)``,
``xi = x / l``, ``b = beta l`` and ``omega^2 = b^4 EI / (rho A l^4)``:

* tip (xi = 1): ``W'' = 0`` and ``W''' = -mu b^4 W`` with ``mu = m_E / (rho A l)``;
* clamped root: ``W = W' = 0``;
* pinned root with hub inertia: ``W = 0`` and ``W'' = -j b^4 W'`` with
  ``j = J1 / (rho A l^3)``.

The clamped case reduces to the classical
``1 + cos b cosh b + mu b (cos b sinh b - sin b cosh b) = 0``.

References
----------
.. [1] Meirovitch, L., *Fundamentals of Vibrations*, McGraw-Hill, 2001, Sec. 8.
.. [2] Laura, P. A. A., Pombo, J. L., Susemihl, E. A., "A note on the vibrations
       of a clamped-free beam with a mass at the free end", J. Sound Vib. 37
       (1974) 161-168.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import scipy.optimize

from mbs_models.parameters import ManipulatorParameters

__all__ = [
    "HUB_CONDITIONS",
    "ModesResult",
    "analytic_frequencies",
    "analytic_beta_l",
    "exudyn_frequencies",
]

logger = logging.getLogger(__name__)

#: Hub boundary conditions understood here.
HUB_CONDITIONS = ("clamped", "pinned")

#: Eigenvalues ``omega^2`` below this fraction of the largest one are rigid-body
#: modes (round-off of the singular stiffness matrix of the pinned hub).
RIGID_MODE_RTOL = 1e-12

#: Grid spacing (in ``beta l``) used to bracket roots of the frequency equation;
#: consecutive roots are at least ~pi/2 apart.
BRACKET_STEP = 0.05


@dataclass(frozen=True)
class ModesResult:
    """Natural frequencies of the link.

    Attributes
    ----------
    frequencies_hz : ndarray
        The lowest ``count`` elastic natural frequencies in Hz, ascending.
    analytic_hz : ndarray
        Euler-Bernoulli frequencies of the same boundary problem where they
        exist (bending modes), else an empty array.
    hub : str
        ``"clamped"`` or ``"pinned"``.
    elements : int
        Number of ANCF elements.
    rigid_modes : int
        Rigid-body modes found (0 Hz) and left out of ``frequencies_hz``.
    params : ManipulatorParameters
        The physical data used.
    """

    frequencies_hz: np.ndarray
    analytic_hz: np.ndarray
    hub: str
    elements: int
    rigid_modes: int
    params: ManipulatorParameters = field(repr=False)

    @property
    def relative_errors(self) -> np.ndarray:
        """``(f_exudyn - f_analytic) / f_analytic`` for the analytic entries."""
        k = min(len(self.analytic_hz), len(self.frequencies_hz))
        return (self.frequencies_hz[:k] - self.analytic_hz[:k]) / self.analytic_hz[:k]

    def to_dict(self) -> dict:
        """JSON-ready dict (keys ``frequencies_hz``, ``analytic_hz``, ...)."""
        return {
            "hub": self.hub,
            "elements": self.elements,
            "rigid_modes": self.rigid_modes,
            "frequencies_hz": [float(f) for f in self.frequencies_hz],
            "analytic_hz": [float(f) for f in self.analytic_hz],
            "relative_errors": [float(e) for e in self.relative_errors],
        }


def _check_hub(hub: str) -> None:
    if hub not in HUB_CONDITIONS:
        raise ValueError(f"hub must be one of {', '.join(HUB_CONDITIONS)}, got {hub!r}")


def _check_count(count: int) -> int:
    if isinstance(count, bool) or int(count) != count or count < 1:
        raise ValueError(f"count must be a positive integer, got {count!r}")
    return int(count)


# --------------------------------------------------------------------------- analytic
def _frequency_determinant(b: float, mu: float, j: Optional[float]) -> float:
    """Determinant of the boundary-condition matrix (``j=None``: clamped root)."""
    c, s, ch, sh = math.cos(b), math.sin(b), math.cosh(b), math.sinh(b)
    # derivatives of (cos, sin, cosh, sinh)(b xi) w.r.t. xi at xi = 1, divided by b^k
    W = [c, s, ch, sh]
    W2 = [-c, -s, ch, sh]
    W3 = [s, -c, sh, ch]
    b4 = b**4
    rows = [
        W2,
        [W3[i] * b**3 + mu * b4 * W[i] for i in range(4)],
    ]
    if j is None:
        rows += [[1.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 1.0]]
    else:
        # W(0) = 0 and W''(0) + j b^4 W'(0) = 0 with W'(0) = b [0, 1, 0, 1], W''(0) = b^2 [-1, 0, 1, 0]
        rows += [[1.0, 0.0, 1.0, 0.0], [-b * b, j * b4 * b, b * b, j * b4 * b]]
    # scale by cosh to keep the determinant O(1) for large b
    return float(np.linalg.det(np.array(rows))) / ch


def analytic_beta_l(params: ManipulatorParameters, hub: str = "clamped", count: int = 2) -> np.ndarray:
    """Roots ``beta l`` of the Euler-Bernoulli frequency equation (elastic modes).

    Parameters
    ----------
    params : ManipulatorParameters
        Link, tip mass and hub inertia.
    hub : {"clamped", "pinned"}
        Boundary condition at the hub.
    count : int
        Number of roots.

    Returns
    -------
    ndarray, shape (count,)
        Ascending roots (the zero root of the pinned rigid-body mode excluded).
    """
    _check_hub(hub)
    count = _check_count(count)
    mu = params.tip_mass / params.link_mass
    j = None if hub == "clamped" else params.hub_inertia / (params.mass_per_length * params.length**3)
    roots: list = []
    a = BRACKET_STEP
    fa = _frequency_determinant(a, mu, j)
    while len(roots) < count:
        b = a + BRACKET_STEP
        fb = _frequency_determinant(b, mu, j)
        if fa == 0.0:
            roots.append(a)
        elif fa * fb < 0.0:
            roots.append(scipy.optimize.brentq(_frequency_determinant, a, b, args=(mu, j), xtol=1e-15, rtol=4 * np.finfo(float).eps))
        a, fa = b, fb
        if a > 1e3:
            raise RuntimeError(f"frequency equation: found only {len(roots)} roots below beta l = 1000")
    return np.array(roots[:count])


def analytic_frequencies(params: ManipulatorParameters, hub: str = "clamped", count: int = 2) -> np.ndarray:
    """Euler-Bernoulli natural frequencies in Hz (see :func:`analytic_beta_l`)."""
    bl = analytic_beta_l(params, hub, count)
    l = params.length
    return bl**2 / (2.0 * math.pi * l * l) * math.sqrt(params.bending_stiffness / params.mass_per_length)


# --------------------------------------------------------------------------- Exudyn
def exudyn_frequencies(
    params: Optional[ManipulatorParameters] = None,
    *,
    elements: int = 8,
    hub: str = "clamped",
    count: int = 4,
    analytic_count: int = 2,
) -> ModesResult:
    """Natural frequencies of the Exudyn ANCF model (gravity off, link straight).

    Parameters
    ----------
    params : ManipulatorParameters, optional
        Physical data (default Table 1).
    elements : int
        Number of ANCF elements (>= 1).
    hub : {"clamped", "pinned"}
        Hub held fixed, or free to rotate with inertia ``J1``.
    count : int
        Number of elastic frequencies to return (bending and axial, ascending).
    analytic_count : int
        Number of Euler-Bernoulli bending frequencies to put beside them.

    Returns
    -------
    ModesResult

    Raises
    ------
    ValueError
        On an unknown hub condition, a non-positive count, or zero elements.

    Notes
    -----
    The built-in model file ``single-link`` (:mod:`mbs_models.builtin.single_link`) at rest along
    the x-axis (hub angle 0, no motion, gravity off), the hub angle held by one more
    ``CoordinateConstraint`` when clamped; eigenvalues of Exudyn's ODE2 mass matrix and stiffness
    Jacobian ``-df/dq`` projected onto the null space of the constraint Jacobian
    (``ComputeODE2Eigenvalues``: exact at the unloaded reference, where ``f = 0`` and the
    constraint reactions vanish).  Frequencies ``sqrt(lambda)/(2 pi)``.
    """
    import exudyn as exu
    from exudyn.itemInterface import CoordinateConstraint

    from mbs_models.builtin.single_link import build
    from mbs_models.console import exudyn_console

    _check_hub(hub)
    count = _check_count(count)
    params = ManipulatorParameters() if params is None else params
    with exudyn_console(True):
        sc = exu.SystemContainer()
        mbs = sc.AddSystem()
        drives = build(mbs, 1.0, elements=elements, params=params, mean_angle=0.0, amplitude=0.0, gravity=False)
        if hub == "clamped":
            mbs.AddObject(CoordinateConstraint(markerNumbers=list(drives[0]["markers"])))
        mbs.Assemble()
        lam, _ = mbs.ComputeODE2Eigenvalues(useAbsoluteValues=False)
    lam = np.sort(np.asarray(lam, dtype=float))
    # the clamped beam has no rigid-body mode; the pinned one has exactly one (rotation about O,
    # gravity off). A relative threshold alone misfires at fine meshes, where the highest axial
    # eigenvalue is ~1e10 times the first bending one.
    rigid = np.zeros(lam.shape, dtype=bool)
    if hub == "pinned":
        rigid[int(np.argmin(np.abs(lam)))] = True
        rigid |= lam < RIGID_MODE_RTOL * np.max(np.abs(lam))
    n_rigid = int(np.count_nonzero(rigid))
    freqs = np.sqrt(lam[~rigid]) / (2.0 * math.pi)
    analytic = analytic_frequencies(params, hub, analytic_count) if analytic_count > 0 else np.array([])
    logger.info("Exudyn %s modes (%d elements): %s Hz", hub, elements, freqs[:count])
    return ModesResult(
        frequencies_hz=freqs[:count],
        analytic_hz=analytic,
        hub=hub,
        elements=int(elements),
        rigid_modes=n_rigid,
        params=params,
    )
