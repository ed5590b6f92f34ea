"""The paper's procedure for the monodromy matrix (Section 2, Eqs. 7-8).

``n`` initial-value problems ``x' = P(t) x``, ``x(0) = e_i`` (the unit
vectors, Eq. 7), are integrated over ``[0, T]`` with ``scipy.integrate.solve_ivp``
and their end states are the columns of ``Phi(T)`` (Eq. 8).  It is slow but
independent of the Magnus machinery, so it serves as the reference method.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["ReferenceOptions", "paper_monodromy"]


@dataclass(frozen=True)
class ReferenceOptions:
    """Options of the reference integration.

    Attributes
    ----------
    integrator : str
        A ``solve_ivp`` method; ``"Radau"`` (implicit, given the exact
        Jacobian ``P(t)``) copes with the stiff controlled cases.
    rtol, atol : float
        Tolerances passed to ``solve_ivp``.
    """

    integrator: str = "Radau"
    rtol: float = 1e-11
    atol: float = 1e-13


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
    n = P(0.0).shape[0]
    Phi = np.empty((n, n))
    nfev = 0
    implicit = options.integrator in ("Radau", "BDF", "LSODA")
    for i in range(n):
        x0 = np.zeros(n)
        x0[i] = 1.0
        kwargs = {"jac": lambda t, x: P(t)} if implicit else {}
        sol = solve_ivp(
            lambda t, x: P(t) @ x,
            (0.0, period),
            x0,
            method=options.integrator,
            rtol=options.rtol,
            atol=options.atol,
            **kwargs,
        )
        if not sol.success:
            raise RuntimeError(f"solve_ivp ({options.integrator}) failed on column {i}: {sol.message}")
        Phi[:, i] = sol.y[:, -1]
        nfev += sol.nfev
    return Phi, nfev
