"""Monodromy by a Magnus product over very many steps, formed chunk by chunk (bounded memory).

:func:`stability.floquet` keeps all ``N`` sub-interval factors in memory, which caps
``N`` at a few thousand for a 40 x 40 system.  Some problems need far more steps to
converge: a finite-element model with stiff undamped modes (kHz) whose
exponential-midpoint product suffers step-size resonances until ``h omega_max`` is
small.  Here the factors are computed and multiplied ``chunk`` at a time, so memory is
``O(chunk n^2)`` whatever ``N``; the cost is ``N`` exponentials and ``N`` products.

Used as an independent time-stepping check of :mod:`stability.hill` (no shared code
beyond the periodic-matrix evaluation).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stability.expm import expm_stack
from stability.floquet import _balancing_scale, _samples
from stability.magnus import MAGNUS2, MAGNUS4, MAGNUS6, magnus_exponents, ordered_product
from stability.periodic import PeriodicMatrixFunction, check_period

__all__ = ["StreamedFloquetResult", "streamed_floquet"]

_SCHEMES = {"magnus2": MAGNUS2, "magnus4": MAGNUS4, "magnus6": MAGNUS6}


@dataclass(frozen=True)
class StreamedFloquetResult:
    """Multipliers from :func:`streamed_floquet`.

    Attributes
    ----------
    multipliers : ndarray of complex
        Eigenvalues of the monodromy, by decreasing modulus.
    monodromy : ndarray
        ``Phi(T)`` (unbalanced).
    n_steps : int
    method : str
    period : float
    elapsed : float
        Seconds.
    """

    multipliers: np.ndarray
    monodromy: np.ndarray = field(repr=False)
    n_steps: int
    method: str
    period: float
    elapsed: float = 0.0

    def nearest(self, z: complex) -> complex:
        """The multiplier nearest ``z``."""
        return complex(self.multipliers[int(np.argmin(np.abs(self.multipliers - z)))])


def streamed_floquet(P: Any, period: float, n_steps: int, *, method: str = "magnus2",
                     chunk: int = 1024) -> StreamedFloquetResult:
    """Monodromy of ``x' = P(t) x`` by ``n_steps`` Magnus factors, multiplied ``chunk`` at a time.

    Parameters
    ----------
    P : periodic matrix
        Callable ``t -> (n, n)``, optionally with ``evaluate(times)``.
    period : float
    n_steps : int
        Sub-intervals (any positive integer).
    method : {"magnus2", "magnus4", "magnus6"}
    chunk : int
        Factors held in memory at once.

    Returns
    -------
    StreamedFloquetResult

    Raises
    ------
    ValueError
        Bad arguments.
    ArithmeticError
        The product overflowed.
    """
    if method not in _SCHEMES:
        raise ValueError(f"method must be one of {', '.join(sorted(_SCHEMES))}, got {method!r}")
    for name, v in (("n_steps", n_steps), ("chunk", chunk)):
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    t0 = time.perf_counter()
    T = check_period(period)
    scheme = _SCHEMES[method]
    wrapped = PeriodicMatrixFunction(P, T)
    n = wrapped.n
    scale = _balancing_scale(_samples(wrapped, T))
    h = T / n_steps
    nodes = np.asarray(scheme.nodes)
    Phi = np.eye(n)
    for start in range(0, int(n_steps), int(chunk)):
        steps = np.arange(start, min(int(n_steps), start + int(chunk)))
        times = ((steps[:, None] + nodes[None, :]) * h).ravel()
        Pt = wrapped.evaluate(times)
        if scale is not None:
            Pt = Pt * (scale[None, :] / scale[:, None])[None]
        with np.errstate(over="ignore", invalid="ignore"):
            E = expm_stack(magnus_exponents(scheme, Pt.reshape(steps.size, nodes.size, n, n), h))
            Phi = ordered_product(E) @ Phi
        if not np.all(np.isfinite(Phi)):
            raise ArithmeticError(f"{method}: the product overflowed after {steps[-1] + 1} of {n_steps} steps")
    if scale is not None:
        Phi = Phi * scale[:, None] / scale[None, :]
    w = np.linalg.eigvals(Phi)
    w = w[np.argsort(-np.abs(w), kind="stable")]
    return StreamedFloquetResult(multipliers=w, monodromy=Phi, n_steps=int(n_steps), method=method, period=T,
                                 elapsed=time.perf_counter() - t0)
