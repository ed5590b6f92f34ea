"""The paper's procedure for the monodromy matrix (Section 2, Eqs. 7-8).

``n`` initial-value problems ``x' = P(t) x``, ``x(0) = e_i`` (the unit
vectors, Eq. 7), are integrated over ``[0, T]`` with ``scipy.integrate.solve_ivp``
and their end states are the columns of ``Phi(T)`` (Eq. 8).  It is slow but
independent of the Magnus machinery, so it serves as the reference method.

The integrator is chosen from the stiffness of ``P`` unless the caller names
one: an implicit method (Radau, given the exact Jacobian ``P(t)``) when the
fastest decay dominates the oscillations, else DOP853.  Radau at
``rtol = 1e-11`` on the uncontrolled manipulator (eigenvalues of ``P`` up to
675i 1/s, 107 oscillations per period at ``Omega = 2 pi``) takes longer than
ten minutes; DOP853 takes seconds, and in the stiff controlled cases DOP853
would be held to steps of ``~3/|lambda|`` by stability alone.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ReferenceOptions", "paper_monodromy", "choose_integrator", "STIFFNESS_RATIO"]

#: ``P`` is called stiff when ``max(-Re lambda) > STIFFNESS_RATIO * max(|Im lambda|, 2 pi / T)``
#: at some sample time: the fastest decay is then far faster than anything the solution
#: does, and an explicit method's step would be set by stability instead of accuracy.
STIFFNESS_RATIO = 3.0
#: Sample times (fractions of the period) for the stiffness test.
STIFFNESS_SAMPLES = 8


@dataclass(frozen=True)
class ReferenceOptions:
    """Options of the reference integration.

    Attributes
    ----------
    integrator : str
        A ``solve_ivp`` method, or ``"auto"`` (default): ``"Radau"`` with the
        exact Jacobian for a stiff ``P``, ``"DOP853"`` otherwise (see
        :func:`choose_integrator`).
    rtol, atol : float
        Tolerances passed to ``solve_ivp``.
    """

    integrator: str = "auto"
    rtol: float = 1e-11
    atol: float = 1e-13


def choose_integrator(P, period: float) -> str:
    """``"Radau"`` if ``P`` is stiff over the period (see :data:`STIFFNESS_RATIO`), else ``"DOP853"``."""
    lam = np.concatenate([np.linalg.eigvals(P(k * period / STIFFNESS_SAMPLES)) for k in range(STIFFNESS_SAMPLES)])
    decay = float(np.max(-lam.real))
    oscillation = max(float(np.max(np.abs(lam.imag))), 2.0 * math.pi / period)
    return "Radau" if decay > STIFFNESS_RATIO * oscillation else "DOP853"


def paper_monodromy(P, period: float, options: ReferenceOptions = ReferenceOptions()) -> tuple[np.ndarray, int]:
    """Monodromy matrix by ``n`` integrations from the unit vectors.

    Parameters
    ----------
    P : callable
        ``t -> (n, n)`` (validated periodic matrix).
    period : float
    options : ReferenceOptions

    Returns
    -------
    Phi : ndarray, shape (n, n)
    nfev : int
        Total number of right-hand-side evaluations.

    Raises
    ------
    RuntimeError
        If an integration fails.
    """
    from scipy.integrate import solve_ivp

    n = P(0.0).shape[0]
    Phi = np.empty((n, n))
    nfev = 0
    integrator = choose_integrator(P, period) if options.integrator == "auto" else options.integrator
    implicit = integrator in ("Radau", "BDF", "LSODA")
    for i in range(n):
        x0 = np.zeros(n)
        x0[i] = 1.0
        kwargs = {"jac": lambda t, x: P(t)} if implicit else {}
        sol = solve_ivp(
            lambda t, x: P(t) @ x,
            (0.0, period),
            x0,
            method=integrator,
            rtol=options.rtol,
            atol=options.atol,
            **kwargs,
        )
        if not sol.success:
            raise RuntimeError(f"solve_ivp ({integrator}) failed on column {i}: {sol.message}")
        Phi[:, i] = sol.y[:, -1]
        nfev += sol.nfev
    return Phi, nfev
