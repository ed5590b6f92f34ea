"""The one rule that chooses a Floquet engine from the system's properties.

Maths
-----
Let ``lambda_i(t)`` be the eigenvalues of the frozen matrix ``P(t)`` and ``w_i(t) = |Im lambda_i(t)|``
(sorted) the frozen oscillation rates.  Two numbers describe what a time-stepping engine faces:

``stiffness = T max_t max_i w_i(t)``
    the radians the fastest frozen oscillation turns in one period.  The Magnus engines in the
    model's coordinates resolve it only with steps ``h w <~ 1``, i.e. about ``stiffness`` steps.
``frozen_rotation = max_i T mean_t |w_i(t) - mean_t w_i|``
    the radians left per period once each frozen mode's mean rotation is taken out -- what the
    frozen-modal frame (:mod:`stability.modal`, an exact similarity in which the stiff part of ``P``
    is nearly constant) leaves for its steps to resolve.  It is small when the stiff modes keep
    their frequencies over the period (a link turning rigidly about a hub) and large when the
    configuration changes them (an elbow that bends couples the axial and bending modes of the two
    links differently along the period).

The rule (:func:`choose_method`), with the step budgets of the engines:

1. ``stiffness <= magnus_steps`` (default ``stability.floquet.MAX_STEPS``): ``"magnus"`` -- the
   adaptive 6th-order Magnus engine resolves every frozen oscillation within its budget;
2. else ``frozen_rotation / sqrt(rtol) <= modal_steps`` (default :data:`MODAL_MAX_STEPS`): ``"modal"``
   -- the exponential midpoint rule (order 2) in the frozen-modal frame makes a relative error of
   about ``(frozen_rotation / N)^2`` with ``N`` steps, so it needs ``N ~ frozen_rotation / sqrt(rtol)``
   steps for the requested accuracy ``rtol``, within its budget;
3. else, when the system offers sampled trigonometric ``M, C, K`` (a smooth second-order system,
   no declared breakpoints):
   ``"hill"`` -- harmonic balance has no step count, so no step-size resonance;
4. else ``"modal"`` (the best a time-stepping engine can do; its estimate says how well).

The requested accuracy ``rtol`` also goes to the engine chosen, which certifies its number to it (or
raises).  Measured (16 frozen samples, gains 0, Omega = 2 pi / 4 pi / 8 pi, ``rtol = 2.5e-4``, a tuning
tolerance of ``1e-3 rho_d`` over 4): the built-in single link (2-16 elements per link) needs 10 / 44-80 /
354-718 frozen-modal steps, the two-link arm (1-4 elements per link) 32900-36200 / 16500-18300 /
8400-9600; the reduced model and the rigid pendulums are not stiff (``stiffness`` 10-114 radians).  ``"paper"`` (the independent reference) and ``"implicit"`` (only the largest moduli)
are never chosen by the rule; ask for them by name.  The rule reads matrices only, never a model's
name.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from stability.floquet import DEFAULT_RTOL

__all__ = ["SystemProperties", "system_properties", "choose_method", "MODAL_MAX_STEPS", "PROPERTY_SAMPLES"]

#: Step budget of the frozen-modal engine in the rule (the largest step count a tuning plant of the
#: package uses, ``flexstab.plants.MAX_TUNING_STEPS``).
MODAL_MAX_STEPS = 4096
#: Times per period at which ``P(t)`` is frozen to measure the properties.
PROPERTY_SAMPLES = 16


@dataclass(frozen=True)
class SystemProperties:
    """What :func:`choose_method` reads (see the module docstring for the definitions).

    Attributes
    ----------
    size : int
        States ``n``.
    period : float
    stiffness : float
        ``T max |Im lambda(P(t))|`` (radians per period).
    frozen_rotation : float
        ``max_i T mean_t |w_i(t) - mean w_i|`` (radians per period).
    trigonometric : bool
        The system offers sampled ``M, C, K`` (attributes ``M``, ``C``, ``K`` of shape ``(N, m, m)``)
        and declares no ``breakpoints`` (a piecewise-sampled system is neither equispaced nor smooth,
        so its trigonometric interpolant is wrong): Hill's method applies.
    """

    size: int
    period: float
    stiffness: float
    frozen_rotation: float
    trigonometric: bool


def _period(system: Any, period: Optional[float]) -> float:
    T = period if period is not None else getattr(system, "period", None)
    if T is None or not (math.isfinite(float(T)) and float(T) > 0):
        raise ValueError(f"a positive finite period is needed, got {T!r}")
    return float(T)


def _samples(system: Any, times: np.ndarray) -> np.ndarray:
    if hasattr(system, "evaluate"):
        return np.asarray(system.evaluate(times), dtype=float)
    return np.array([np.asarray(system(t), dtype=float) for t in times])


def system_properties(system: Any, period: Optional[float] = None, *,
                      samples: int = PROPERTY_SAMPLES) -> SystemProperties:
    """Measure :class:`SystemProperties` of ``x' = P(t) x`` from ``samples`` frozen ``P(t)``.

    ``system`` is what :func:`stability.engines.floquet` accepts: a callable ``t -> P(t)`` (with
    ``period``), or an object with ``.period`` and ``evaluate(times)`` or ``__call__``.
    """
    T = _period(system, period)
    times = T * np.arange(samples) / samples
    P = _samples(system, times)
    if P.ndim != 3 or P.shape[1] != P.shape[2] or not np.all(np.isfinite(P)):
        raise ValueError(f"P(t) must be finite square matrices, got shape {P.shape}")
    rates = np.sort(np.abs(np.linalg.eigvals(P).imag), axis=1)  # (samples, n): frozen rates, sorted
    stiffness = float(T * rates.max())
    rotation = float(T * np.max(np.mean(np.abs(rates - rates.mean(axis=0)), axis=0)))
    mats = [getattr(system, k, None) for k in ("M", "C", "K")]
    trig = all(isinstance(a, np.ndarray) and a.ndim == 3 for a in mats) and not getattr(system, "breakpoints", ())
    return SystemProperties(size=int(P.shape[1]), period=T, stiffness=stiffness, frozen_rotation=rotation,
                            trigonometric=trig)


def choose_method(props: SystemProperties, *, rtol: float = DEFAULT_RTOL, magnus_steps: Optional[int] = None,
                  modal_steps: int = MODAL_MAX_STEPS) -> str:
    """The engine for a system with ``props`` and the requested relative accuracy ``rtol``: the rule
    of the module docstring (``"magnus"``, ``"modal"`` or ``"hill"``)."""
    if not (math.isfinite(rtol) and 0 < rtol < 1):
        raise ValueError(f"rtol must be in (0, 1), got {rtol!r}")
    if magnus_steps is None:
        from stability.floquet import MAX_STEPS

        magnus_steps = MAX_STEPS
    if props.stiffness <= magnus_steps:
        return "magnus"
    if props.frozen_rotation <= modal_steps * math.sqrt(rtol):
        return "modal"
    return "hill" if props.trigonometric else "modal"
