"""Dominant Floquet multipliers of large systems without forming the monodromy matrix.

Public entry point: :func:`implicit_floquet`.

The one-period map ``x -> Phi(T) x`` is applied as the product of the
sub-interval propagators ``E_N ... E_1`` (the Magnus factors of
:mod:`stability.floquet`, computed once) to one vector at a time: ``N``
matrix-vector products of cost ``n^2`` instead of the ``N`` matrix-matrix
products of cost ``n^3`` that form ``Phi``.  ARPACK's implicitly restarted
Arnoldi method (``scipy.sparse.linalg.eigs`` on a ``LinearOperator``) finds
the ``k`` multipliers of largest modulus.

Certification
-------------
Each Ritz pair ``(rho, v)`` is checked by one more application of the map:
the relative residual ``eta = ||Phi v - rho v|| / (|rho| ||v||)`` says that
``rho`` is an exact multiplier of ``Phi + Delta`` with ``||Delta|| = eta |rho|``
(a backward error; the forward error is at most the eigenvalue condition
number times that).  A multiplier is *certified* when ``eta`` is at most
:data:`RESIDUAL_TOL`; the result lists which ones are.  The discretisation
error of the propagators themselves is estimated as in the dense method, by
repeating the computation with half the sub-intervals (Richardson).

References
----------
.. [1] Lehoucq, R. B., Sorensen, D. C., Yang, C., *ARPACK Users' Guide*,
       SIAM, 1998 (implicitly restarted Arnoldi).
.. [2] Lust, K., "Improved numerical Floquet multipliers", Int. J. Bifurcation
       and Chaos 11 (2001) 2389-2410 (matrix-free Floquet multipliers of large
       systems).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigs

from stability.expm import expm_stack
from stability.floquet import (
    FloquetError,
    _Balanced,
    _balancing_scale,
    _check_period_scale,
    _memory_check,
    _samples,
)
from stability.magnus import MAGNUS2, MAGNUS4, MAGNUS6, MagnusScheme, magnus_exponents
from stability.periodic import PeriodicMatrixFunction
from stability.serialization import json_ready

__all__ = ["ImplicitFloquetResult", "implicit_floquet", "propagators", "RESIDUAL_TOL"]

#: Largest relative residual ``||Phi v - rho v|| / (|rho| ||v||)`` of a certified multiplier.
RESIDUAL_TOL = 1e-10
#: Convergence tolerance handed to ARPACK (relative accuracy of the Ritz values).
ARNOLDI_TOL = 1e-13
_SCHEMES = {"magnus2": MAGNUS2, "magnus4": MAGNUS4, "magnus6": MAGNUS6}


@dataclass(frozen=True)
class ImplicitFloquetResult:
    """Dominant Floquet multipliers from Arnoldi iterations on the one-period map.

    Attributes
    ----------
    multipliers : ndarray, complex, shape (k,)
        The ``k`` multipliers of largest modulus found, sorted by modulus,
        descending.
    residuals : ndarray, shape (k,)
        Relative residual of each (see the module notes).
    certified : ndarray of bool, shape (k,)
        ``residuals <= RESIDUAL_TOL``: these are multipliers of the computed
        one-period map to that backward error.
    error_estimate : float
        Richardson estimate of the discretisation error of the certified
        moduli (from ``n_steps // 2``); NaN when not computed.
    n_steps : int
    n_matvecs : int
        Applications of the one-period map (all runs included).
    method : str
    period : float
    elapsed : float
    """

    multipliers: np.ndarray
    residuals: np.ndarray
    certified: np.ndarray
    error_estimate: float
    n_steps: int
    n_matvecs: int
    method: str
    period: float
    elapsed: float = 0.0

    @property
    def moduli(self) -> np.ndarray:
        """``|rho_i|``, descending."""
        return np.abs(self.multipliers)

    @property
    def spectral_radius(self) -> float:
        """Largest certified modulus (NaN if none is certified)."""
        mods = self.moduli[self.certified]
        return float(mods[0]) if mods.size else math.nan

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return json_ready({
            "multipliers": [[float(z.real), float(z.imag)] for z in self.multipliers],
            "moduli": self.moduli,
            "residuals": self.residuals,
            "certified": [bool(c) for c in self.certified],
            "error_estimate": self.error_estimate,
            "n_steps": self.n_steps,
            "n_matvecs": self.n_matvecs,
            "method": self.method,
            "period": self.period,
            "elapsed": self.elapsed,
        })


def propagators(wrapped: Any, period: float, n_steps: int, scheme: MagnusScheme) -> np.ndarray:
    """Sub-interval propagators ``E_k`` (shape ``(N, n, n)``, time order) of ``wrapped``."""
    n = wrapped.n
    _memory_check(scheme, n_steps, n)
    h = period / n_steps
    nodes = np.asarray(scheme.nodes)
    times = (np.arange(n_steps)[:, None] + nodes[None, :]) * h
    Pg = wrapped.evaluate(times.ravel()).reshape(n_steps, len(nodes), n, n)
    with np.errstate(over="ignore", invalid="ignore"):
        E = expm_stack(magnus_exponents(scheme, Pg, h))
    if not np.all(np.isfinite(E)):
        raise FloquetError(f"{scheme.name}: a propagator overflowed with {n_steps} sub-intervals")
    return E


def _one_period_operator(E: np.ndarray, counter: list) -> LinearOperator:
    n = E.shape[-1]

    def matvec(v: np.ndarray) -> np.ndarray:
        counter[0] += 1
        x = np.asarray(v).reshape(n, -1)
        for Ek in E:
            x = Ek @ x
        return x

    return LinearOperator((n, n), matvec=matvec, matmat=matvec, dtype=float)


def _arnoldi(E: np.ndarray, k: int, counter: list, seed: int):
    n = E.shape[-1]
    op = _one_period_operator(E, counter)
    v0 = np.random.default_rng(seed).standard_normal(n)
    ncv = min(n, max(2 * k + 1, k + 12))
    try:
        vals, vecs = eigs(op, k=k, which="LM", v0=v0, tol=ARNOLDI_TOL, ncv=ncv, maxiter=50 * n)
    except ArpackNoConvergence as exc:  # keep what converged; the residual check decides
        vals, vecs = exc.eigenvalues, exc.eigenvectors
    order = np.lexsort((-vals.imag, -np.abs(vals)))
    vals, vecs = vals[order], vecs[:, order]
    # one more application of the map per Ritz vector: the residual check
    applied = op.matmat(vecs.real) + 1j * op.matmat(vecs.imag)
    norms = np.linalg.norm(vecs, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        res = np.linalg.norm(applied - vecs * vals[None, :], axis=0) / (np.abs(vals) * norms)
    res = np.where(np.isfinite(res), res, np.inf)
    return vals, res


def implicit_floquet(
    P: Any,
    period: Optional[float] = None,
    *,
    k: int = 6,
    n_steps: int = 512,
    method: str = "magnus2",
    error_estimate: bool = True,
    balance: bool = True,
    seed: int = 0,
) -> ImplicitFloquetResult:
    """The ``k`` Floquet multipliers of largest modulus, matrix-free.

    Parameters
    ----------
    P : callable or periodic-system object
        As for :func:`stability.floquet`.
    period : float, optional
    k : int
        Number of multipliers wanted (``1 <= k <= n - 2``, ARPACK's limit for
        real operators).
    n_steps : int
        Sub-intervals of the propagator product.
    method : {"magnus2", "magnus4", "magnus6"}
        Magnus scheme of the propagators.
    error_estimate : bool
        Repeat with ``n_steps // 2`` sub-intervals for a Richardson estimate of
        the discretisation error.
    balance : bool
        Work with the diagonally balanced ``D^-1 P D`` (same multipliers).
    seed : int
        Seed of the Arnoldi start vector.

    Returns
    -------
    ImplicitFloquetResult

    Raises
    ------
    ValueError
        On invalid arguments (as :func:`stability.floquet`, and ``k`` out of range).
    FloquetError
        If a propagator overflows.
    """
    t0 = time.perf_counter()
    if method not in _SCHEMES:
        raise ValueError(f"method must be one of {', '.join(sorted(_SCHEMES))}, got {method!r}")
    if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 2:
        raise ValueError(f"n_steps must be an integer >= 2, got {n_steps!r}")
    wrapped = PeriodicMatrixFunction(P, period)
    T = wrapped.period
    n = wrapped.n
    if isinstance(k, bool) or int(k) != k or not 1 <= k <= n - 2:
        raise ValueError(f"k must be an integer in [1, n - 2] = [1, {n - 2}], got {k!r}")
    samples = _samples(wrapped, T)
    scale = _balancing_scale(samples) if balance else None
    _check_period_scale(samples, T, scale)
    target = wrapped if scale is None else _Balanced(wrapped, scale)
    scheme = _SCHEMES[method]
    counter = [0]
    vals, res = _arnoldi(propagators(target, T, int(n_steps), scheme), int(k), counter, seed)
    certified = res <= RESIDUAL_TOL
    est = math.nan
    if error_estimate:
        coarse, _ = _arnoldi(propagators(target, T, int(n_steps) // 2, scheme), int(k), counter, seed)
        mods, cmods = np.abs(vals), np.sort(np.abs(coarse))[::-1]
        keep = certified & (mods >= 1e-6 * mods[0])
        if np.any(keep):
            factor = 2.0**scheme.order - 1.0
            est = float(np.max(np.abs(cmods[: mods.size][keep] / mods[keep] - 1.0))) / factor
    return ImplicitFloquetResult(
        multipliers=vals,
        residuals=res,
        certified=certified,
        error_estimate=est,
        n_steps=int(n_steps),
        n_matvecs=counter[0],
        method=method,
        period=T,
        elapsed=time.perf_counter() - t0,
    )
