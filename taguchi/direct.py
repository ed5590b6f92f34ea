"""Direct optimisation of the PD gains, for comparison with the Taguchi tuning.

The same objective as :func:`taguchi.tuning.taguchi_tune` -- drive
``y(kp, kd) = max|rho|`` to ``rho_d`` -- minimised with ``scipy.optimize``:
``"nelder-mead"`` (from the centre of the ranges, bounded) or
``"differential-evolution"`` (over the ranges).  The search stops as soon as
an evaluation lands within the tolerance, so the evaluation counts of both
approaches are comparable.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from taguchi.tuning import STATUS_BUDGET, STATUS_CONVERGED, NamedGains, TuningConfig

__all__ = ["DirectResult", "direct_tune", "DIRECT_METHODS"]

DIRECT_METHODS = ("nelder-mead", "differential-evolution")


@dataclass(frozen=True)
class DirectResult(NamedGains):
    """Outcome of :func:`direct_tune` (fields as :class:`~taguchi.tuning.TaguchiResult`)."""

    gains: tuple[float, ...]
    names: tuple[str, ...]
    spectral_radius: float
    target: float
    tolerance: float
    converged: bool
    status: str
    method: str
    evaluations: int
    elapsed: float

    def to_dict(self) -> dict:
        """JSON-ready dictionary (one key per factor, plus ``gains`` and ``names``)."""
        out = {s: float(v) for s, v in zip(self.names, self.gains)}
        out.update(dict(self.__dict__))
        out["gains"], out["names"] = list(self.gains), list(self.names)
        return out


class _Reached(Exception):
    pass


def direct_tune(
    objective: Callable[[Sequence[float]], float],
    config: TuningConfig = TuningConfig(),
    method: str = "nelder-mead",
    seed: int = 0,
) -> DirectResult:
    """Minimise ``(max|rho| - rho_d)^2`` over the gain ranges with ``scipy.optimize``.

    Parameters
    ----------
    objective : callable
        ``gains -> max|rho|``, gains in the order of ``config.names``.
    config : TuningConfig
        Target, ranges, tolerance and evaluation budget.
    method : {"nelder-mead", "differential-evolution"}
    seed : int
        Seed of differential evolution.

    Returns
    -------
    DirectResult
    """
    if method not in DIRECT_METHODS:
        raise ValueError(f"unknown direct method {method!r}; choose from {', '.join(DIRECT_METHODS)}")
    t0 = time.perf_counter()
    target, tol = config.target, config.effective_tolerance
    bounds = list(config.factor_ranges)
    best = {"y": math.inf, "x": tuple(math.nan for _ in bounds), "n": 0}

    def loss(x: np.ndarray) -> float:
        if best["n"] >= config.max_evaluations:
            raise _Reached
        gains = tuple(float(v) for v in x)
        y = float(objective(gains))
        best["n"] += 1
        if abs(y - target) < abs(best["y"] - target):
            best["y"], best["x"] = y, gains
        if abs(y - target) <= tol:
            raise _Reached
        return (y - target) ** 2

    from scipy.optimize import differential_evolution, minimize  # on use: ~0.25 s of imports

    try:
        if method == "nelder-mead":
            x0 = np.array([np.mean(b) for b in bounds])
            minimize(loss, x0, method="Nelder-Mead", bounds=bounds,
                     options={"xatol": 1e-8, "fatol": 0.0, "maxfev": config.max_evaluations})
        else:
            differential_evolution(loss, bounds, seed=seed, tol=0.0, maxiter=10_000, polish=False)
    except _Reached:
        pass
    converged = abs(best["y"] - target) <= tol
    return DirectResult(
        gains=best["x"],
        names=tuple(config.names),
        spectral_radius=best["y"],
        target=target,
        tolerance=tol,
        converged=converged,
        status=STATUS_CONVERGED if converged else STATUS_BUDGET,
        method=method,
        evaluations=best["n"],
        elapsed=time.perf_counter() - t0,
    )
