"""Robust design of the PD gains against payload, frequency and stiffness uncertainty.

Glue between the model-free :mod:`taguchi.robust` and the models: a plant
factory maps the noise values of an outer run (``tip_mass`` in kg,
``omega_scale``, ``youngs_modulus_scale``) to a plant, and
:func:`compare_nominal_robust` tunes the gains twice -- nominally (Eq. 34 at
the nominal noise) and robustly (crossed arrays) -- and judges both by the
worst-case ``max|rho|`` over a fine full-factorial grid of the noise box (not
the outer array).
"""
from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Optional

from mbs_models.parameters import ManipulatorParameters
from taguchi.robust import (
    PlantNoiseObjective,
    RobustConfig,
    RobustResult,
    WorstCase,
    noise_grid,
    robust_tune,
    worst_case,
)
from taguchi.tuning import TaguchiResult, TuningConfig, taguchi_tune

__all__ = ["ReducedNoisePlant", "RobustComparison", "compare_nominal_robust"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReducedNoisePlant:
    """``noise -> ReducedModel`` for the single link (picklable).

    ``noise`` may hold ``tip_mass`` (kg), ``omega_scale`` and
    ``youngs_modulus_scale``; missing ones take the nominal values.
    """

    omega: float
    params: ManipulatorParameters = dataclasses.field(default_factory=ManipulatorParameters)
    constants: str = "auto"

    def __call__(self, noise: Mapping[str, float]):
        from mbs_models.reduced import ReducedModel

        p = dataclasses.replace(
            self.params,
            tip_mass=float(noise.get("tip_mass", self.params.tip_mass)),
            youngs_modulus=self.params.youngs_modulus * float(noise.get("youngs_modulus_scale", 1.0)),
        )
        return ReducedModel(omega=self.omega * float(noise.get("omega_scale", 1.0)), params=p,
                            constants=self.constants)


@dataclass(frozen=True)
class RobustComparison:
    """Nominal against robust gains, judged over a fine noise grid.

    Attributes
    ----------
    nominal : TaguchiResult
        Tuning to ``rho_d`` at the nominal noise values.
    robust : RobustResult
        Crossed-array tuning.
    nominal_check, robust_check : WorstCase
        Both gain sets over the grid.
    worst_case_improvement : float
        ``nominal_check.worst - robust_check.worst`` (> 0: the robust gains
        lower the worst case).
    nominal_cost : float
        ``|robust_check.nominal - rho_d| - |nominal_check.nominal - rho_d|``:
        how much further from ``rho_d`` the robust gains are at nominal noise.
    elapsed : float
    """

    nominal: TaguchiResult
    robust: RobustResult
    nominal_check: WorstCase
    robust_check: WorstCase
    worst_case_improvement: float
    nominal_cost: float
    elapsed: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "target": self.nominal.target,
            "nominal": {"gains": list(self.nominal.gains), "names": list(self.nominal.names),
                        "evaluations": self.nominal.evaluations, "converged": self.nominal.converged,
                        **self.nominal_check.to_dict()},
            "robust": {**self.robust.to_dict(), "check": self.robust_check.to_dict()},
            "worst_case_improvement": self.worst_case_improvement,
            "worst_case_improvement_percent": 100 * self.worst_case_improvement / self.nominal_check.worst,
            "nominal_cost": self.nominal_cost,
            "grid_size": self.robust_check.grid_size,
            "elapsed": self.elapsed,
        }


def compare_nominal_robust(
    factory: Callable[[Mapping[str, float]], Any],
    tuning: TuningConfig,
    robust: RobustConfig,
    *,
    grid_points: int = 7,
    executor: Optional[cf.Executor] = None,
    floquet_options: Optional[dict] = None,
) -> RobustComparison:
    """Tune nominally and robustly, then judge both over a ``grid_points^k`` noise grid.

    Parameters
    ----------
    factory : callable
        ``noise -> plant`` (e.g. :class:`ReducedNoisePlant`).
    tuning : TuningConfig
        Target and gain ranges of the nominal tuning.
    robust : RobustConfig
        The robust design (its ``tuning`` is normally ``tuning`` with a larger budget).
    grid_points : int
        Points per noise factor of the worst-case grid.
    executor : concurrent.futures.Executor, optional
        Runs the experiments' runs and the grid.
    floquet_options : dict, optional
        Options of :func:`stability.floquet` inside the loops.
    """
    t0 = time.perf_counter()
    objective = PlantNoiseObjective(factory, floquet_options)
    nominal_noise = robust.nominal_noise
    nominal = taguchi_tune(_AtNoise(objective, nominal_noise), tuning, executor=executor)
    logger.info("nominal tuning: %s, %d evaluations, %.1f s", nominal.status, nominal.evaluations,
                time.perf_counter() - t0)
    rob = robust_tune(objective, robust, executor=executor)
    logger.info("robust tuning: %s, %d evaluations, %.1f s", rob.status, rob.evaluations, time.perf_counter() - t0)
    grid = noise_grid(robust.noise, grid_points)
    nc = worst_case(objective, nominal.gains, grid, nominal_noise, executor=executor)
    logger.info("worst case of the nominal gains over %d grid points, %.1f s", len(grid), time.perf_counter() - t0)
    rc = worst_case(objective, rob.gains, grid, nominal_noise, executor=executor)
    target = tuning.target
    return RobustComparison(
        nominal=nominal, robust=rob, nominal_check=nc, robust_check=rc,
        worst_case_improvement=nc.worst - rc.worst,
        nominal_cost=abs(rc.nominal - target) - abs(nc.nominal - target),
        elapsed=time.perf_counter() - t0,
    )


class _AtNoise:
    """``gains -> objective(gains, noise)`` at fixed noise (picklable)."""

    def __init__(self, objective: Callable, noise: Mapping[str, float]) -> None:
        self.objective, self.noise = objective, dict(noise)

    def __call__(self, gains) -> float:
        return float(self.objective(tuple(gains), self.noise))
