"""One refinement loop: double a discretisation until its step-doubling estimate meets a tolerance.

Every "double the steps (or harmonics) until ``c |r_n - r_2n| <= tol``" of the package is this loop
(:func:`double_until`); the callers differ only in what they evaluate and in the constant ``c`` of
their estimate.

Maths
-----
For a value ``r_n`` converging like ``r_n = r + C n^-p``, ``|r_n - r| = 2^p / (2^p - 1) |r_n - r_2n|``
asymptotically; ``c = 4/3`` (``p = 2``) bounds it for every observed order ``p >= 2``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

__all__ = ["Refinement", "double_until", "pair_estimate", "PAIR_FACTOR"]

#: ``c`` of the estimate ``c |r_n - r_2n|``: ``2^p / (2^p - 1)`` at ``p = 2``, which bounds the error of
#: ``r_n`` for every observed order ``p >= 2`` (the factor falls with ``p``; see the module notes).
PAIR_FACTOR = 4.0 / 3.0


def pair_estimate(r_n: float, r_2n: float, factor: float = PAIR_FACTOR) -> float:
    """The step-doubling error estimate ``factor |r_n - r_2n|`` of ``r_n`` (one pair; :func:`double_until`
    repeats it until it meets a tolerance)."""
    return float(factor * abs(r_n - r_2n))


@dataclass(frozen=True)
class Refinement:
    """Outcome of :func:`double_until`.

    Attributes
    ----------
    n : int
        The count returned: the coarser count ``m`` of the pair ``(m, 2m)`` that met the tolerance, or,
        when ``n_max`` stopped the doubling first, the last count evaluated.
    value : float
        The value at ``n``.
    estimate : float
        ``factor |r_m - r_2m|`` of the last pair compared (it bounds the error of ``r_m``; when the cap
        stopped the doubling ``m = n / 2``, so it over-states the error of the returned finer ``n``);
        NaN when no pair fitted under the cap.
    converged : bool
        Whether ``estimate <= tolerance``.
    evaluations : int
    """

    n: int
    value: float
    estimate: float
    converged: bool
    evaluations: int


def double_until(value_at: Callable[[int], float], n0: int, n_max: int, tolerance: float, *,
                 factor: float = PAIR_FACTOR) -> Refinement:
    """Evaluate ``value_at(n)`` at ``n0, 2 n0, 4 n0, ...`` (at most ``n_max``) until
    ``factor |r_n - r_2n| <= tolerance``; see :class:`Refinement` for what is returned (``n0`` itself,
    not converged, when ``2 n0 > n_max``)."""
    if not (isinstance(n0, int) and n0 >= 1):
        raise ValueError(f"n0 must be an integer >= 1, got {n0!r}")
    if not (tolerance > 0 and math.isfinite(tolerance)):
        raise ValueError(f"tolerance must be positive and finite, got {tolerance!r}")
    n, r = n0, value_at(n0)
    evaluations, estimate = 1, math.nan
    while 2 * n <= n_max:
        r2 = value_at(2 * n)
        evaluations += 1
        estimate = pair_estimate(r, r2, factor)
        if estimate <= tolerance:
            return Refinement(n=n, value=r, estimate=float(estimate), converged=True, evaluations=evaluations)
        n, r = 2 * n, r2
    return Refinement(n=n, value=r, estimate=float(estimate), converged=False, evaluations=evaluations)
