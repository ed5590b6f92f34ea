"""Dominant Floquet multipliers of large systems without forming the monodromy matrix.

Public entry point: :func:`implicit_floquet`.

The one-period map ``x -> Phi(T) x`` is applied as the product of the
sub-interval propagators ``E_N ... E_1`` (the Magnus factors of
:mod:`stability.floquet`, computed once) to one vector at a time: ``N``
matrix-vector products of cost ``n^2`` instead of the ``N`` matrix-matrix
products of cost ``n^3`` that form ``Phi``.  ARPACK's implicitly restarted
Arnoldi method (``scipy.sparse.linalg.eigs`` on a ``LinearOperator``) finds
the ``k`` multipliers of largest modulus.

Which multipliers
-----------------
"Dominant" means *largest modulus*: ARPACK's ``which="LM"``.  Krylov methods on
the map ``Phi`` (polynomials in ``Phi``) find the eigenvalues on the outer
boundary of the spectrum; by the maximum-modulus principle no polynomial
separates an eigenvalue inside the disc of the others, so a damped multiplier
lying inside a ring of multipliers on the unit circle (the PD-damped hub mode
of an undamped flexible link at 0.99 inside the elastic modes at 1 - 1e-7) is
out of reach of this method, however many iterations it runs.  The multipliers
it returns are the ones that decide stability (the spectral radius); when many
of them share nearly the same modulus (a cluster on the unit circle) the Arnoldi
iteration converges slowly and only some of the ``k`` are certified.

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
    MEMORY_LIMIT,
    FloquetError,
    _Balanced,
    _balancing_scale,
    _check_period_scale,
    _samples,
    _stream_chunk,
)
from stability.magnus import MAGNUS2, MAGNUS4, MAGNUS6, MagnusScheme, magnus_exponents
from stability.frozen import frozen_result
from stability.periodic import PeriodicMatrixFunction
from stability.serialization import json_ready

__all__ = ["ImplicitFloquetResult", "implicit_floquet", "propagators", "residuals", "RESIDUAL_TOL"]

#: Largest relative residual ``||Phi v - rho v|| / (|rho| ||v||)`` of a certified multiplier.
RESIDUAL_TOL = 1e-10
#: Convergence tolerance handed to ARPACK (relative accuracy of the Ritz values).
ARNOLDI_TOL = 1e-13
_SCHEMES = {"magnus2": MAGNUS2, "magnus4": MAGNUS4, "magnus6": MAGNUS6}


@frozen_result
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
        moduli (from ``n_steps // 2``, or for ``magnus2`` with ``n_steps`` a
        multiple of 3 from ``n_steps / 3``: the map of the cubes of every third
        factor, no new propagators); NaN when not computed.
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
    """Sub-interval propagators ``E_k`` (shape ``(N, n, n)``, time order) of ``wrapped``.

    Formed in chunks of sub-intervals (the work arrays of one chunk within
    :data:`stability.floquet.CHUNK_MEMORY`), so that memory is the ``N n^2``
    of the result itself; that must be within :data:`stability.floquet.MEMORY_LIMIT`.
    """
    n = wrapped.n
    need = 8.0 * n_steps * n * n
    if need > MEMORY_LIMIT:
        raise FloquetError(f"{scheme.name}: {n_steps} propagators of {n}x{n} need {need / 1e9:.1f} GB "
                           f"(limit {MEMORY_LIMIT / 1e9:.1f} GB of work arrays)")
    h = period / n_steps
    nodes = np.asarray(scheme.nodes)
    E = np.empty((n_steps, n, n))
    chunk = _stream_chunk(scheme, n)
    for start in range(0, n_steps, chunk):
        idx = np.arange(start, min(n_steps, start + chunk))
        times = (idx[:, None] + nodes[None, :]) * h
        Pg = wrapped.evaluate(times.ravel()).reshape(idx.size, len(nodes), n, n)
        with np.errstate(over="ignore", invalid="ignore"):
            E[idx] = expm_stack(magnus_exponents(scheme, Pg, h))
    if not np.all(np.isfinite(E)):
        raise FloquetError(f"{scheme.name}: a propagator overflowed with {n_steps} sub-intervals")
    return E


def _one_period_operator(E: np.ndarray, counter: list, power: int = 1) -> LinearOperator:
    """``x -> E_N^p ... E_1^p x`` (``p = power``), matrix-free."""
    n = E.shape[-1]

    def matvec(v: np.ndarray) -> np.ndarray:
        counter[0] += 1
        x = np.asarray(v).reshape(n, -1)
        for Ek in E:
            for _ in range(power):
                x = Ek @ x
        return x

    return LinearOperator((n, n), matvec=matvec, matmat=matvec, dtype=float)


def residuals(E: np.ndarray, values: np.ndarray, vectors: np.ndarray, power: int = 1) -> np.ndarray:
    """Relative residuals ``||Phi v - rho v|| / (|rho| ||v||)`` of eigenpairs of the map ``Phi = E_N ... E_1``.

    The certificate of :func:`implicit_floquet` (one application of the map per
    pair); ``inf`` where it is not finite (e.g. ``rho = 0``).
    """
    op = _one_period_operator(E, [0], power)
    vecs = np.asarray(vectors, dtype=complex).reshape(E.shape[-1], -1)
    vals = np.asarray(values, dtype=complex).ravel()
    applied = op.matmat(vecs.real) + 1j * op.matmat(vecs.imag)
    norms = np.linalg.norm(vecs, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        res = np.linalg.norm(applied - vecs * vals[None, :], axis=0) / (np.abs(vals) * norms)
    return np.where(np.isfinite(res), res, np.inf)


def _arnoldi(E: np.ndarray, k: int, counter: list, seed: int, power: int = 1):
    n = E.shape[-1]
    op = _one_period_operator(E, counter, power)
    v0 = np.random.default_rng(seed).standard_normal(n)
    ncv = min(n, max(2 * k + 1, k + 12))
    try:
        vals, vecs = eigs(op, k=k, which="LM", v0=v0, tol=ARNOLDI_TOL, ncv=ncv, maxiter=50 * n)
    except ArpackNoConvergence as exc:  # keep what converged; the residual check decides
        vals, vecs = exc.eigenvalues, exc.eigenvectors
    order = np.lexsort((-vals.imag, -np.abs(vals)))
    vals, vecs = vals[order], vecs[:, order]
    # one more application of the map per Ritz vector: the residual check
    counter[0] += 2
    return vals, residuals(E, vals, vecs, power)


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
    target = wrapped if scale is None else _Balanced(wrapped, scale)
    _check_period_scale(samples, T, None if scale is None else target.ratio)
    scheme = _SCHEMES[method]
    counter = [0]
    E = propagators(target, T, int(n_steps), scheme)
    vals, res = _arnoldi(E, int(k), counter, seed)
    certified = res <= RESIDUAL_TOL
    est = math.nan
    if error_estimate:
        if scheme.order == 2 and n_steps % 3 == 0:
            # the exponential midpoint rule with N/3 steps is E_{3j+1}^3 (see floquet._third_companion)
            coarse, _ = _arnoldi(E[1::3], int(k), counter, seed, power=3)
            ratio = 3.0
        else:
            coarse, _ = _arnoldi(propagators(target, T, int(n_steps) // 2, scheme), int(k), counter, seed)
            ratio = 2.0
        mods, cmods = np.abs(vals), np.sort(np.abs(coarse))[::-1]
        keep = certified & (mods >= 1e-6 * mods[0])
        if np.any(keep):
            factor = ratio**scheme.order - 1.0
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
