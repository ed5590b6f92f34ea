"""One call from a model to labelled Floquet multipliers: orbit -> linearisation -> Floquet."""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np
import scipy.linalg

from linearize.constrained import linearize_orbit
from linearize.periodic_orbit import DEFAULT_SAMPLES, PeriodicOrbit, find_orbit
from linearize.system import LinearizedPeriodicSystem

__all__ = [
    "DEFAULT_PROPAGATOR_STEPS",
    "UNDAMPED_TOLERANCE",
    "ModelFloquetResult",
    "analyze",
    "label_multipliers",
]

logger = logging.getLogger(__name__)

#: Sub-intervals of the exponential-midpoint (``magnus2``) product.
DEFAULT_PROPAGATOR_STEPS = 512
#: ``| |rho| - 1 | <`` this: an undamped mode (on the unit circle within the propagator's accuracy).
UNDAMPED_TOLERANCE = 2e-3


@dataclass(frozen=True)
class ModelFloquetResult:
    """Floquet analysis of a model file about its periodic orbit.

    Attributes
    ----------
    floquet : stability.FloquetResult
    modes : list of dict
        Per multiplier (same order): ``modulus``, ``mode`` (label), ``group``
        (Exudyn item holding most of the Floquet vector's energy), ``shares``
        (energy fraction per item and per drive coordinate), ``frequency_hz``
        (of the frozen-time mode it resembles most), ``mac``, ``undamped``.
    dominant_multiplier : complex
        Largest multiplier not on the unit circle (else the largest).
    orbit : PeriodicOrbit
    linearization : LinearizedPeriodicSystem
    kp, kd : tuple of float
        Gains per drive.
    timings : dict
        Seconds per stage.
    """

    floquet: Any
    modes: list
    dominant_multiplier: complex
    orbit: PeriodicOrbit = field(repr=False)
    linearization: LinearizedPeriodicSystem = field(repr=False)
    kp: tuple = ()
    kd: tuple = ()
    timings: dict = field(default_factory=dict)

    @property
    def drives(self) -> tuple:
        return self.orbit.drive_names

    @property
    def orbit_residual(self) -> float:
        return float(self.orbit.residual)

    def summary(self) -> dict:
        d = self.dominant_multiplier
        return {
            "model": self.orbit.model.name,
            "drives": list(self.drives),
            "orbit_residual": self.orbit_residual,
            "shooting_residual": float(self.orbit.shooting_residual),
            "samples": self.orbit.samples,
            "ode2": self.orbit.size,
            "independent_coordinates": self.linearization.size,
            "dominant_multiplier": [float(d.real), float(d.imag)],
            "dominant_modulus": float(abs(d)),
            "modes": self.modes,
            "timings": dict(self.timings),
        }


def label_multipliers(lin: LinearizedPeriodicSystem, orbit: PeriodicOrbit, floquet_result: Any) -> list:
    """Label each multiplier by where its Floquet vector lives (see :class:`ModelFloquetResult`)."""
    raise NotImplementedError


def analyze(
    model: Any,
    omega: float,
    *,
    kp: "float | Sequence[float]" = 0.0,
    kd: "float | Sequence[float]" = 0.0,
    samples: int = DEFAULT_SAMPLES,
    method: str = "magnus2",
    n_steps: Optional[int] = DEFAULT_PROPAGATOR_STEPS,
    orbit: Optional[PeriodicOrbit] = None,
    verify_orbit: bool = True,
    **options: Any,
) -> ModelFloquetResult:
    """Orbit, constraint-correct linearisation and labelled Floquet multipliers of a model.

    Parameters
    ----------
    model : ModelDefinition, str, path or callable
        Built-in name, model file path, :class:`~mbs_models.model_file.ModelDefinition`
        or a ``build(mbs, omega)`` callable.
    omega : float
    kp, kd : float or sequence
        PD gains per drive (or one for all).
    samples : int
        Collocation / linearisation samples per period.
    method, n_steps :
        :func:`stability.floquet` method and sub-intervals (``n_steps=None``: adaptive).
    orbit : PeriodicOrbit, optional
        Reuse an orbit.
    verify_orbit : bool
        Shooting check of the orbit in Exudyn.
    **options
        Keyword options of the model's ``build``.
    """
    raise NotImplementedError
