"""Hill's method: an adapter to :func:`stability.hill.hill_multipliers`."""
from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from stability.engines.base import Engine, FloquetSolution, _sorted, register

__all__ = ["HillEngine"]


@register
class HillEngine(Engine):
    """Harmonic balance on a second-order system's sampled trigonometric ``M, C, K``.

    ``system`` carries ``M, C, K`` of shape ``(N, n, n)`` (samples at ``k T / N``) and ``.period``
    (e.g. :class:`linearize.system.LinearizedPeriodicSystem`); ``targets`` (required) are the
    approximate multipliers to refine, ``harmonics`` the ``H`` (default 16).  No step count, so no
    step-size resonance; certified by the H vs H/2 estimate (and each pair's backward error).
    """

    name = "hill"
    options = frozenset({"targets", "harmonics", "error_estimate"})
    complete = False

    def run(self, system: Any, period: Optional[float], rtol: float, **options: Any) -> Any:
        from stability.hill import hill_multipliers

        mats = [getattr(system, k, None) for k in ("M", "C", "K")]
        if not all(isinstance(a, np.ndarray) and a.ndim == 3 for a in mats):
            raise ValueError("hill: the system must carry sampled M, C, K of shape (N, n, n)")
        if getattr(system, "breakpoints", ()):
            raise ValueError("hill: the system is sampled piece by piece (it declares breakpoints): its "
                             "coefficients are not smooth, so harmonic balance does not apply; use magnus or modal")
        if "targets" not in options:
            raise ValueError("hill: targets (approximate multipliers to refine) are required")
        T = period if period is not None else system.period
        return hill_multipliers(*mats, float(T), options["targets"], harmonics=options.get("harmonics", 16),
                                error_estimate=options.get("error_estimate", True))

    def solution(self, result: Any) -> FloquetSolution:
        est = np.asarray(result.error_estimate, dtype=float)
        order = np.argsort(-np.abs(result.multipliers), kind="stable")
        return FloquetSolution(multipliers=_sorted(result.multipliers),
                               spectral_radius=float(np.max(np.abs(result.multipliers))),
                               error_estimate=float(np.max(est[order])) if est.size and np.all(np.isfinite(est))
                               else math.nan,
                               complete=False, method=self.name, period=float(result.period), detail=result)
