"""Iterative Taguchi tuning of the PD gains to a target Floquet multiplier.

The objective is the paper's Eq. (34): drive ``y(kp, kd) = max_i |rho_i|``
to the target ``rho_d``.  Any number of factors is tuned the same way (two
drives: ``(kp1, kd1, kp2, kd2)``, :attr:`TuningConfig.ranges`).  One
*iteration* is one Taguchi experiment:

1. **Levels.** Each factor (``kp``, ``kd``, ...) gets ``levels`` equally
   spaced values spanning its current range ``[lo, hi]`` (ends included).
2. **Array.** The runs are the rows of an orthogonal array with one column
   of ``levels`` levels per factor (default for 3 levels: L9 up to 4
   factors, L18 up to 7, L27 up to 13; ``array=`` chooses another, e.g.
   ``"L25"`` with 5 levels).  The runs are independent and go
   through a ``concurrent.futures`` executor.
3. **S/N.** Each run's response ``y`` gets the target S/N ratio
   ``eta = -10 log10 (y - rho_d)^2`` (:func:`taguchi.sn.sn_target`).
4. **Analysis.** Response table (mean S/N per level, delta, rank), ANOVA
   percentage contributions and the best level of each factor (largest mean
   S/N); the additive model predicts the S/N at those levels.
5. **Confirmation.** One run at the best levels; its S/N is recorded beside
   the prediction.
6. **Incumbent.** The best point so far is the run (array or confirmation,
   this or an earlier iteration) with the smallest ``|y - rho_d|``.  The
   main-effect optimum alone is not always the best run here, because the
   gains with ``max|rho| = rho_d`` form a curve in the (kp, kd) plane, which
   an additive model describes only locally.
7. **Re-centre and shrink.** Each range is re-centred on the incumbent and
   its width multiplied by ``shrink`` (default 0.5); a range is shifted, not
   cut, to stay within the user's initial range, which is the constraint
   ``u_min <= u <= u_max`` of the paper's Eq. (12): the returned gains always
   lie inside it.
8. **Stop** when ``|y_incumbent - rho_d| <= tolerance`` (default
   ``1e-3 rho_d``) -- status ``"converged"`` -- or when the next iteration
   would exceed ``max_evaluations`` -- status ``"budget exhausted"``, with
   the best point reached -- or when ``rho_d`` is out of the search's reach
   -- status ``"target unreachable"`` (below).

**Unreachable targets.** Each window is centred on a point of the one
before and ``shrink`` times as wide, so every later run lies within the
current window widened to ``width / (1 - shrink)`` per factor (twice the
width for ``shrink = 0.5``).  If the responses of an experiment vary by
``spread`` (max - min over its runs and its confirmation), a response that
changed linearly over that reach would vary by ``spread / (1 - shrink)``.
The tuning stops when, on :data:`UNREACHABLE_PATIENCE` consecutive
experiments, the remaining gap ``|y_incumbent - rho_d| - tolerance``
exceeds :data:`UNREACHABLE_SAFETY` times that linear reach: the windows
shrink onto a point (typically a corner of the ranges) whose response does
not come near ``rho_d``.  It stops at once when every run of an experiment
has the same response (the windows have collapsed, or the response does
not depend on the factors there: the experiment holds no information and
its ANOVA contributions would be undefined, :func:`taguchi.analysis.is_constant`),
and when every window is narrower than :data:`COLLAPSED_RTOL` of its
initial width.  Status ``"target unreachable"`` when every run so far lay
on one side of rho_d (the message names the factors whose best value lies
at an end of its initial range: the ranges to widen); ``"search stalled"``
when runs on both sides were seen -- rho_d then lies inside the ranges (the
response is continuous in the gains), between the incumbent and the run the
message names, and the windows shrank onto a point away from it.

**Failed runs.** A run whose objective raises a numerical error
(:data:`RUN_FAILURES`: the engines' ``FloquetError``, ``HillError``,
``ModalBasisError``, ``numpy.linalg.LinAlgError`` or ``FloatingPointError``)
does not abort the tuning,
as a diverging simulation does not abort a physical experiment: the run is
recorded (``failures`` of its iteration, ``failed_runs`` of the result, with
the error), its response is NaN (``null`` in JSON), it is scored with the
worst S/N of the experiment's other runs and never becomes the incumbent; a
failed confirmation run has S/N NaN (``null`` in JSON).  Any other
exception -- a plain ``ZeroDivisionError`` or ``OverflowError`` is a
programming error, not a failed experiment -- propagates.
When every run of an experiment fails, the tuning stops: with
``ArithmeticError`` naming the first failure if no run has succeeded yet,
else with status ``"runs failed"`` and the best point reached.

This is the sequential "iterative Taguchi" scheme of range reduction about
the current optimum used by Khang et al. for tuned-mass dampers (the
paper's Refs. [10, 11]); the paper does not print its own rule, so the one
above is ours.

References
----------
.. [1] Phadke, M. S., *Quality Engineering Using Robust Design*, Prentice
       Hall, 1989.
.. [2] Khang, N. V., et al., optimal TMD parameters by the Taguchi method
       (the reference paper's Refs. [10, 11]).
.. [3] Dat, D. C., Khang, N. V., Hoang, N. Q., Quyen, N. V., the reference
       paper, Sec. 4.2 and Eq. (34).
"""
from __future__ import annotations

import concurrent.futures as cf
import logging
import math
import time
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Callable, Optional, Sequence

import numpy as np

from stability.floquet import FloquetError
from stability.frozen import frozen_result
from stability.gains import Gains, MeasuredPlant, Plant
from stability.hill import HillError
from stability.modal import ModalBasisError
from taguchi.analysis import TaguchiAnalysis, analyze, is_constant
from taguchi.arrays import OrthogonalArray, array_for, get_array, to_design
from taguchi.sn import sn_target

__all__ = [
    "GainObjective",
    "plant_response",
    "TaguchiIteration",
    "TaguchiResult",
    "TuningConfig",
    "check_gain_range",
    "default_factor_names",
    "recentre",
    "taguchi_tune",
    "STATUS_CONVERGED",
    "STATUS_BUDGET",
    "STATUS_FAILED",
    "STATUS_UNREACHABLE",
    "STATUS_STALLED",
    "RUN_FAILURES",
    "LOOP_FLOQUET_OPTIONS",
    "UNREACHABLE_PATIENCE",
    "UNREACHABLE_SAFETY",
    "COLLAPSED_RTOL",
]

logger = logging.getLogger(__name__)

STATUS_CONVERGED = "converged"
STATUS_BUDGET = "budget exhausted"
STATUS_FAILED = "runs failed"
STATUS_UNREACHABLE = "target unreachable"
STATUS_STALLED = "search stalled"
#: Consecutive experiments on which the gap to rho_d must exceed the search's linear reach before the
#: tuning stops as unreachable (one experiment could be a badly placed window).
UNREACHABLE_PATIENCE = 2
#: Safety factor on the linear reach ``spread / (1 - shrink)`` (room for curvature of the response).
UNREACHABLE_SAFETY = 2.0
#: A window narrower than this fraction of its initial range has collapsed (its levels are a few
#: rounding units apart: ~2**-43 after 43 halvings).
COLLAPSED_RTOL = 1e-13
#: Exceptions of one run that are recorded as a failed run instead of aborting :func:`taguchi_tune`:
#: the numerical failures the engines raise.  Not the ``ArithmeticError`` base, whose built-in
#: ``ZeroDivisionError``/``OverflowError`` are programming errors and must propagate.
RUN_FAILURES = (FloquetError, HillError, ModalBasisError, np.linalg.LinAlgError, FloatingPointError)
#: :func:`stability.floquet` options of a run inside the loop (:class:`GainObjective`): a fixed number of
#: sub-intervals without step doubling; the caller re-checks the final gains with the adaptive method.
LOOP_FLOQUET_OPTIONS = MappingProxyType({"n_steps": 256, "error_estimate": False})


class GainObjective:
    """``(kp1, kd1, kp2, kd2, ...) -> response`` of a plant: the one adapter from a run's gains to a plant.

    The run's interleaved gains become :class:`stability.gains.Gains` (one ``(kp, kd)`` pair per
    drive; an odd count is a ``ValueError``) and reach the plant as :meth:`~stability.gains.Gains.arguments`
    gives them (floats for one drive, one value per drive otherwise).

    Parameters
    ----------
    plant : stability.gains.MeasuredPlant or stability.gains.Plant
        A :class:`~stability.gains.MeasuredPlant` supplies its own response
        ``spectral_measure(kp, kd)`` (a model file's dominant labelled multiplier).  Otherwise
        the response is the spectral radius of ``stability.floquet(plant.with_gains(kp, kd),
        **floquet_options)`` (e.g. :class:`mbs_models.reduced.ReducedModel` or a
        linearisation).  Must be picklable for process or Dask executors.
    floquet_options : dict
        Keyword arguments for :func:`stability.floquet` (a :class:`~stability.gains.Plant` only);
        default :data:`LOOP_FLOQUET_OPTIONS`.
    unit_circle_tolerance : float, optional
        If given (a :class:`~stability.gains.Plant` only), the response is the largest modulus
        among the multipliers off the unit circle (``| |rho| - 1 | >= tolerance``): the
        undamped modes of an FE model without structural damping keep ``|rho| = 1`` whatever the
        gains, and the tuning targets the damped ones.  ``None``: the spectral radius.
    """

    def __init__(self, plant: Any, floquet_options: Optional[dict] = None,
                 unit_circle_tolerance: Optional[float] = None) -> None:
        if not isinstance(plant, (MeasuredPlant, Plant)):
            raise ValueError("plant must provide with_gains(kp, kd) or spectral_measure(kp, kd)")
        self.plant = plant
        self.floquet_options = dict(floquet_options or LOOP_FLOQUET_OPTIONS)
        self.unit_circle_tolerance = unit_circle_tolerance

    def __call__(self, gains: Sequence[float]) -> float:
        return plant_response(self.plant, Gains.from_interleaved(gains), self.floquet_options,
                              self.unit_circle_tolerance)


def plant_response(plant: Any, gains: Gains, floquet_options: Optional[dict] = None,
                   unit_circle_tolerance: Optional[float] = None) -> float:
    """The response of ``plant`` at ``gains`` (the rule of :class:`GainObjective`): its own
    ``spectral_measure`` for a :class:`~stability.gains.MeasuredPlant`, else the (off-unit-circle)
    spectral radius of :func:`stability.floquet` on ``plant.with_gains``."""
    from stability import floquet

    kp, kd = gains.arguments()
    if isinstance(plant, MeasuredPlant):
        return float(plant.spectral_measure(kp, kd))
    res = floquet(plant.with_gains(kp, kd), **dict(floquet_options or LOOP_FLOQUET_OPTIONS))
    if unit_circle_tolerance is None:
        return float(res.spectral_radius)
    moduli = np.abs(np.asarray(res.multipliers))
    off = moduli[np.abs(moduli - 1.0) >= unit_circle_tolerance]
    return float(np.max(off)) if off.size else float(np.max(moduli))


def check_gain_range(value: Any, name: str) -> tuple[float, float]:
    """Validate a gain range ``(low, high)``: finite, ``0 <= low < high``.

    Raises
    ------
    ValueError
        Naming ``name``: not a pair, not finite, negative, empty or inverted.
    """
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (low, high), got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if lo < 0:
        raise ValueError(f"{name}: gains must be >= 0, got low = {lo}")
    if hi <= lo:
        raise ValueError(f"{name} is empty or inverted: ({lo}, {hi})")
    return (lo, hi)


def default_factor_names(n_factors: int) -> tuple[str, ...]:
    """Factor names for ``n_factors`` gains: ``(kp, kd)`` for one drive,
    ``(kp1, kd1, kp2, kd2, ...)`` for several (pairs per drive), else ``x1, x2, ...``."""
    if n_factors == 2:
        return ("kp", "kd")
    if n_factors % 2 == 0:
        return tuple(f"{g}{j + 1}" for j in range(n_factors // 2) for g in ("kp", "kd"))
    return tuple(f"x{j + 1}" for j in range(n_factors))


@dataclass(frozen=True)
class TuningConfig:
    """Options of :func:`taguchi_tune`.

    Attributes
    ----------
    target : float
        ``rho_d`` > 0.
    kp_range, kd_range : (float, float)
        Initial ranges of the two gains of one drive, ``0 <= lo < hi``; used
        when ``ranges`` is not given.
    ranges : sequence of (float, float), optional
        Initial ranges of any number of factors (e.g. ``(kp1, kd1, kp2, kd2)``
        for two drives); overrides ``kp_range``/``kd_range``.
    names : sequence of str, optional
        Factor names (default :func:`default_factor_names`).
    array : str, optional
        Orthogonal array name (``"L9"``, ``"L16"``, ``"L25"``, ``"L27"``, ...);
        default the smallest array with one column of ``levels`` levels per
        factor (:func:`taguchi.arrays.array_for`: L9 for up to 4 factors at
        3 levels, L18 for 5-7, L27 for 8-13).
    levels : int
        Levels per factor when ``array`` is not given (default 3).
    tolerance : float, optional
        Stop when ``|max|rho| - rho_d| <= tolerance``; default ``1e-3 rho_d``.
    max_evaluations : int
        Budget of Floquet evaluations (array runs + confirmations).
    shrink : float
        Range width factor per iteration, ``0 < shrink < 1``.
    """

    target: float = 0.3
    kp_range: tuple[float, float] = (0.0, 60.0)
    kd_range: tuple[float, float] = (0.0, 40.0)
    array: Optional[str] = None
    levels: int = 3
    tolerance: Optional[float] = None
    max_evaluations: int = 600
    shrink: float = 0.5
    ranges: Optional[tuple[tuple[float, float], ...]] = None
    names: Optional[tuple[str, ...]] = None

    def __post_init__(self) -> None:
        if not (isinstance(self.target, (int, float)) and math.isfinite(self.target) and self.target > 0):
            raise ValueError(f"target rho_d must be finite and > 0, got {self.target!r}")
        for name in ("kp_range", "kd_range"):
            object.__setattr__(self, name, check_gain_range(getattr(self, name), name))
        if self.ranges is not None:
            if isinstance(self.ranges, (str, bytes)) or len(self.ranges) < 1:
                raise ValueError(f"ranges must be a non-empty sequence of (low, high) pairs, got {self.ranges!r}")
            n = len(self.ranges)
        else:
            n = 2
        if self.names is not None:
            names = tuple(str(s) for s in self.names)
            if len(names) != n or len(set(names)) != n:
                raise ValueError(f"names must be {n} distinct factor names, got {self.names!r}")
        else:
            names = default_factor_names(n)
        object.__setattr__(self, "names", names)
        if self.ranges is not None:
            object.__setattr__(self, "ranges", tuple(
                check_gain_range(r, f"{s} range") for r, s in zip(self.ranges, names)))
        if isinstance(self.levels, bool) or not isinstance(self.levels, int) or self.levels < 2:
            raise ValueError(f"levels must be an integer >= 2, got {self.levels!r}")
        if self.tolerance is not None and not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"tolerance must be finite and > 0, got {self.tolerance!r}")
        if isinstance(self.max_evaluations, bool) or not isinstance(self.max_evaluations, int) or self.max_evaluations < 1:
            raise ValueError(f"max_evaluations must be a positive integer, got {self.max_evaluations!r}")
        if not (0 < self.shrink < 1):
            raise ValueError(f"shrink must be in (0, 1), got {self.shrink!r}")

    @property
    def factor_ranges(self) -> tuple[tuple[float, float], ...]:
        """Initial range of every factor (``ranges``, or ``(kp_range, kd_range)``)."""
        return self.ranges if self.ranges is not None else (self.kp_range, self.kd_range)

    @property
    def n_factors(self) -> int:
        """Number of tuned factors."""
        return len(self.factor_ranges)

    @property
    def effective_tolerance(self) -> float:
        """The stopping tolerance (``1e-3 rho_d`` unless given)."""
        return self.tolerance if self.tolerance is not None else 1e-3 * self.target

    def orthogonal_array(self) -> OrthogonalArray:
        """The array used for every iteration: one column per factor, equal level counts."""
        n = self.n_factors
        if self.array is None:
            return array_for(n, self.levels)
        oa = get_array(self.array)
        for s in sorted(set(oa.levels), reverse=True):
            cols = oa.columns_with_levels(s)
            if len(cols) >= n:
                return oa.subset(cols[:n])
        raise ValueError(f"array {self.array!r} has no {n} columns with equal level counts")


def _named(names: Sequence[str], values: Sequence[float]) -> dict[str, float]:
    return {s: float(v) for s, v in zip(names, values)}


@dataclass(frozen=True)
class TaguchiIteration:
    """One Taguchi experiment of the tuning history.

    ``ranges[j]``, ``factor_levels[j]`` belong to factor ``names[j]``; the
    ``kp_*``/``kd_*`` properties are those of the first two factors (the
    single-drive case).  A failed run (``failures``) has response NaN; a
    failed confirmation run also has ``confirmation_sn`` NaN (``null`` in JSON).
    """

    index: int
    ranges: tuple[tuple[float, float], ...]
    factor_levels: tuple[tuple[float, ...], ...]
    names: tuple[str, ...]
    design: tuple[tuple[float, ...], ...]
    responses: tuple[float, ...]
    sn_ratios: tuple[float, ...]
    analysis: TaguchiAnalysis
    best_levels: tuple[int, ...]
    predicted_sn: float
    confirmation_gains: tuple[float, ...]
    confirmation_response: float
    confirmation_sn: float
    incumbent_gains: tuple[float, ...]
    incumbent_response: float
    failures: tuple[dict, ...] = ()

    @property
    def kp_range(self) -> tuple[float, float]:
        return self.ranges[0]

    @property
    def kd_range(self) -> tuple[float, float]:
        return self.ranges[1]

    @property
    def kp_levels(self) -> tuple[float, ...]:
        return self.factor_levels[0]

    @property
    def kd_levels(self) -> tuple[float, ...]:
        return self.factor_levels[1]

    def __repr__(self) -> str:  # the design, responses and ANOVA are in to_dict(); keep a REPL readable
        ranges = ", ".join(f"{s}=({r[0]:.6g}, {r[1]:.6g})" for s, r in zip(self.names, self.ranges))
        gains = ", ".join(f"{s}={g:.6g}" for s, g in zip(self.names, self.incumbent_gains))
        return (f"TaguchiIteration(index={self.index}, ranges[{ranges}], runs={len(self.design)}, "
                f"incumbent=({gains}, max|rho|={self.incumbent_response:.6g}))")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``<name>_range``/``<name>_levels`` per factor)."""
        out: dict[str, Any] = {"index": self.index, "names": list(self.names)}
        for s, r in zip(self.names, self.ranges):
            out[f"{s}_range"] = list(r)
        for s, lv in zip(self.names, self.factor_levels):
            out[f"{s}_levels"] = list(lv)
        out.update({
            "design": [list(r) for r in self.design],
            "responses": list(self.responses),
            "sn_ratios": list(self.sn_ratios),
            "response_table": {
                "level_means": [list(m) for m in self.analysis.response_table.level_means],
                "delta": list(self.analysis.response_table.delta),
                "rank": list(self.analysis.response_table.rank),
            },
            "contribution_percent": list(self.analysis.anova.contribution_percent),
            "error_contribution_percent": self.analysis.anova.error_contribution_percent,
            "best_levels": list(self.best_levels),
            "predicted_sn": self.predicted_sn,
            "confirmation": {
                **_named(self.names, self.confirmation_gains),
                "spectral_radius": self.confirmation_response,
                "sn": self.confirmation_sn,
            },
            "incumbent": {
                **_named(self.names, self.incumbent_gains),
                "spectral_radius": self.incumbent_response,
            },
            "failures": [dict(f) for f in self.failures],
        })
        return out


class NamedGains:
    """``kp``/``kd`` of a single-drive tuning result with ``names`` and ``gains`` fields
    (shared by :class:`TaguchiResult` and :class:`taguchi.direct.DirectResult`)."""

    @property
    def kp(self) -> float:
        """``kp`` of a single-drive tuning (use :attr:`gains` for several drives)."""
        return self._named("kp")

    @property
    def kd(self) -> float:
        """``kd`` of a single-drive tuning (use :attr:`gains` for several drives)."""
        return self._named("kd")

    def _named(self, key: str) -> float:
        if key not in self.names:
            raise AttributeError(f"this tuning has factors {', '.join(self.names)}, no {key!r}; use .gains")
        return self.gains[self.names.index(key)]


@frozen_result(repr=False)
@dataclass(frozen=True)
class TaguchiResult(NamedGains):
    """Outcome of :func:`taguchi_tune`.

    Attributes
    ----------
    gains : tuple of float
        The best factor values found, in the order of ``names``.
    names : tuple of str
        Factor names (``("kp", "kd")`` for one drive).
    spectral_radius : float
        ``max|rho|`` at those gains (as evaluated inside the loop).
    target, tolerance : float
    converged : bool
    status : str
        ``"converged"``, ``"budget exhausted"``, ``"target unreachable"`` / ``"search stalled"`` (the
        windows shrink onto a point whose response stays away from rho_d, with every run on one side of
        rho_d / with runs on both sides; module docstring) or ``"runs failed"`` (every run of an
        experiment failed).
    message : str
    evaluations : int
        Floquet evaluations used.
    iterations : tuple of TaguchiIteration
        The full history.
    array : str
        The orthogonal array used.
    elapsed : float
        Wall time in s.
    failed_runs : tuple of dict
        Every run whose objective raised one of :data:`RUN_FAILURES`: ``iteration``, ``run`` (index in
        the array, or ``"confirmation"``), ``gains``, ``error``.
    """

    gains: tuple[float, ...]
    names: tuple[str, ...]
    spectral_radius: float
    target: float
    tolerance: float
    converged: bool
    status: str
    message: str
    evaluations: int
    iterations: tuple[TaguchiIteration, ...]
    array: str
    elapsed: float
    config: TuningConfig = field(repr=False, default_factory=TuningConfig)
    failed_runs: tuple[dict, ...] = ()

    def __repr__(self) -> str:  # one line: the history is summarised, not printed (see ``iterations``)
        gains = ", ".join(f"{s}={g:.6g}" for s, g in zip(self.names, self.gains))
        return (f"TaguchiResult({gains}, spectral_radius={self.spectral_radius:.6g}, "
                f"target={self.target:g}, status={self.status!r}, evaluations={self.evaluations}, "
                f"iterations=<{len(self.iterations)} TaguchiIteration>, array={self.array!r}, "
                f"elapsed={self.elapsed:.3g} s)")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``iterations`` is the history; one key per factor)."""
        out: dict[str, Any] = _named(self.names, self.gains)
        out.update({
            "names": list(self.names),
            "gains": list(self.gains),
            "spectral_radius": self.spectral_radius,
            "target": self.target,
            "tolerance": self.tolerance,
            "converged": self.converged,
            "status": self.status,
            "message": self.message,
            "evaluations": self.evaluations,
            "array": self.array,
            "elapsed": self.elapsed,
            "failed_runs": [dict(f) for f in self.failed_runs],
            "iterations": [it.to_dict() for it in self.iterations],
        })
        return out


def _levels(rng: tuple[float, float], n: int) -> np.ndarray:
    return np.linspace(rng[0], rng[1], n)


def recentre(centre: float, width: float, bounds: tuple[float, float]) -> tuple[float, float]:
    """A window of ``width`` centred on ``centre``, shifted (not cut) to stay inside ``bounds``.

    Parameters
    ----------
    centre, width : float
        Centre and width of the wanted window.
    bounds : (float, float)
        The window is moved (keeping its width where ``bounds`` allow) to lie inside these.

    Returns
    -------
    (float, float)
        ``(lo, hi)`` of the window.
    """
    lo = max(bounds[0], centre - width / 2)
    hi = lo + width
    if hi > bounds[1]:
        hi = bounds[1]
        lo = max(bounds[0], hi - width)
    return (lo, hi)


class _Guarded:
    """``point -> (response, None)``, or ``(nan, "ErrorType: message")`` when the objective raises one of
    :data:`RUN_FAILURES` (picklable if the objective is)."""

    def __init__(self, fn: Callable) -> None:
        self.fn = fn

    def __call__(self, point: tuple) -> tuple[float, Optional[str]]:
        try:
            return float(self.fn(point)), None
        except RUN_FAILURES as exc:
            logger.warning("run at %s failed: %s: %s", point, type(exc).__name__, exc)
            return math.nan, f"{type(exc).__name__}: {exc}"


def _evaluate(fn: Callable, points: list, executor: Optional[cf.Executor]) -> list[tuple[float, Optional[str]]]:
    guarded = _Guarded(fn)
    if executor is None:
        return [guarded(p) for p in points]
    return list(executor.map(guarded, points))


def taguchi_tune(
    objective: Callable[[Sequence[float]], float],
    config: TuningConfig = TuningConfig(),
    *,
    executor: Optional[cf.Executor] = None,
    progress: Any = False,
) -> TaguchiResult:
    """Tune the factors so that ``objective(gains) = max|rho|`` reaches ``config.target``.

    Parameters
    ----------
    objective : callable
        ``gains -> max_i |rho_i|`` with ``gains`` a tuple in the order of
        ``config.names`` (``(kp, kd)`` by default, e.g. :class:`GainObjective`);
        must be picklable when ``executor`` is a process pool or Dask.
    config : TuningConfig
    executor : concurrent.futures.Executor, optional
        Runs the array's rows; default serial in this process.
    progress : bool or callable
        Show a tqdm bar over iterations, or a bar of this factory ``progress(total=, desc=, unit=)``
        (an object with tqdm's ``update`` and ``close``).

    Returns
    -------
    TaguchiResult
        Never raises for an unreachable target: the status says ``"target unreachable"`` or
        ``"search stalled"`` (the search stopped early, module docstring) or ``"budget
        exhausted"``, and the best point reached is returned.

    Raises
    ------
    ValueError
        If the objective returns NaN/inf or a negative value.
    ArithmeticError
        If every run of the first experiment fails (one of :data:`RUN_FAILURES`); single failed
        runs are recorded instead (module docstring, "Failed runs").
    """
    t0 = time.perf_counter()
    oa = config.orthogonal_array()
    n_runs = oa.n_runs
    tol = config.effective_tolerance
    target = config.target
    names = tuple(config.names)  # type: ignore[arg-type]
    bounds = config.factor_ranges
    rngs = tuple(bounds)
    evaluations = 0
    history: list[TaguchiIteration] = []
    best_gains: Optional[tuple[float, ...]] = None
    best_y = math.inf
    failed: list[dict] = []
    all_failed = False
    stalled = 0  # consecutive experiments whose gap to rho_d exceeds the search's linear reach
    out_of_reach: Optional[tuple[float, float]] = None  # the last experiment's response range, if stalled
    flat_at: Optional[str] = None  # why the last experiment holds no information (flat responses, collapsed windows)
    across: list = []  # (response, gains) of every successful run: which sides of rho_d the runs reached

    bar = None
    if progress:
        bar_options = {"total": config.max_evaluations, "desc": f"Taguchi rho_d={target:g}", "unit": "eval"}
        if callable(progress):  # a bar factory (one line per iteration on a pipe, see flexstab.progress)
            bar = progress(**bar_options)
        else:
            from tqdm.auto import tqdm

            bar = tqdm(**bar_options, leave=False)
    try:
        while evaluations + n_runs + 1 <= config.max_evaluations:
            lv_values = [_levels(r, s) for r, s in zip(rngs, oa.levels)]
            design = to_design(oa, [v.tolist() for v in lv_values])
            points = [tuple(float(x) for x in row) for row in design]
            runs = _evaluate(objective, points, executor)
            ys = [y for y, _ in runs]
            fails = [{"iteration": len(history), "run": i, "gains": list(points[i]), "error": err}
                     for i, (_, err) in enumerate(runs) if err is not None]
            good = [i for i, (_, err) in enumerate(runs) if err is None]
            _check_responses([ys[i] for i in good], [points[i] for i in good], names)
            if not good:
                evaluations += n_runs
                failed.extend(fails)
                all_failed = True
                if best_gains is None:
                    f = fails[0]
                    raise ArithmeticError(
                        f"every run of the first Taguchi experiment failed ({n_runs} runs); the first at "
                        + ", ".join(f"{s} = {v:.6g}" for s, v in zip(names, f["gains"])) + f": {f['error']}")
                logger.warning("every run of experiment %d failed: stopping with the best point so far", len(history))
                break
            sn_good = {i: sn_target(ys[i], target) for i in good}
            worst = min(sn_good.values())  # a failed run scores as the worst run of its experiment
            sn = np.array([sn_good.get(i, worst) for i in range(n_runs)])
            if is_constant(sn):  # nothing to analyse: stop with the best run (module docstring)
                evaluations += n_runs
                failed.extend(fails)
                if bar is not None:
                    bar.update(n_runs)
                for i in good:
                    across.append((ys[i], points[i]))
                    if abs(ys[i] - target) < abs(best_y - target):
                        best_y, best_gains = ys[i], points[i]
                flat_at = "every run of the last experiment gave the same response"
                break
            result = analyze(oa, sn, factor_names=names)
            lv = result.best_levels
            conf = tuple(float(v[k]) for v, k in zip(lv_values, lv))
            y_conf, err = _Guarded(objective)(conf)  # one run: no point shipping it to a worker
            if err is None:
                _check_responses([y_conf], [conf], names)
            else:
                fails.append({"iteration": len(history), "run": "confirmation", "gains": list(conf), "error": err})
            failed.extend(fails)
            evaluations += n_runs + 1
            if bar is not None:
                bar.update(n_runs + 1)
            for p, y in list(zip(points, ys)) + [(conf, y_conf)]:
                if not math.isfinite(y):  # a failed run
                    continue
                across.append((y, p))
                if abs(y - target) < abs(best_y - target):
                    best_y, best_gains = y, p
            assert best_gains is not None
            history.append(
                TaguchiIteration(
                    index=len(history),
                    ranges=rngs,
                    factor_levels=tuple(tuple(v.tolist()) for v in lv_values),
                    names=names,
                    design=tuple(points),
                    responses=tuple(ys),
                    sn_ratios=tuple(sn.tolist()),
                    analysis=result,
                    best_levels=tuple(int(k) for k in lv),
                    predicted_sn=float(result.predicted_sn),
                    confirmation_gains=conf,
                    confirmation_response=y_conf,
                    confirmation_sn=float(sn_target(y_conf, target)) if err is None else math.nan,
                    incumbent_gains=best_gains,
                    incumbent_response=best_y,
                    failures=tuple(fails),
                )
            )
            logger.debug("iteration %d: ranges %s -> best %s rho=%.6g", len(history), rngs, best_gains, best_y)
            if abs(best_y - target) <= tol:
                break
            finite = [y for y in list(ys) + [y_conf] if math.isfinite(y)]
            spread = max(finite) - min(finite)
            reach = UNREACHABLE_SAFETY * spread / (1.0 - config.shrink)
            stalled = stalled + 1 if abs(best_y - target) - tol > reach else 0
            if stalled >= UNREACHABLE_PATIENCE:
                out_of_reach = (min(finite), max(finite))
                break
            rngs = tuple(
                recentre(c, (r[1] - r[0]) * config.shrink, b) for c, r, b in zip(best_gains, rngs, bounds)
            )
            if all(r[1] - r[0] <= COLLAPSED_RTOL * (b[1] - b[0]) for r, b in zip(rngs, bounds)):
                flat_at = f"the windows collapsed to below {COLLAPSED_RTOL:.0e} of the ranges"
                break
    finally:
        if bar is not None:
            bar.close()

    if best_gains is None:
        raise ValueError(
            f"max_evaluations = {config.max_evaluations} is smaller than one experiment "
            f"({n_runs} runs + 1 confirmation with {oa.name})"
        )
    converged = abs(best_y - target) <= tol
    unreachable = not converged and (out_of_reach is not None or flat_at is not None)
    seen = (min(across, key=lambda pt: pt[0]), max(across, key=lambda pt: pt[0])) if across else ((best_y, best_gains),) * 2
    status = (STATUS_CONVERGED if converged else STATUS_UNREACHABLE if unreachable
              else STATUS_FAILED if all_failed else STATUS_BUDGET)
    at = ", ".join(f"{s} = {v:.6g}" + _at_bound(v, b) for s, v, b in zip(names, best_gains, bounds))
    if converged:
        message = f"|max|rho| - rho_d| = {abs(best_y - target):.2e} <= {tol:.2e} after {evaluations} evaluations"
    elif unreachable:
        edge = [s for s, v, b in zip(names, best_gains, bounds) if _at_bound(v, b)]
        if flat_at is not None:
            why = flat_at
        else:
            why = (f"the responses of the last {UNREACHABLE_PATIENCE} experiments vary too little to close the gap "
                   f"(last: {out_of_reach[0]:.6g} to {out_of_reach[1]:.6g})")
        done = f"stopped after {evaluations} evaluations in {len(history)} iterations"
        ((y_lo, p_lo), (y_hi, p_hi)) = seen
        if y_lo < target < y_hi:  # rho_d lies inside the ranges (continuity), away from where the search shrank
            other = min((pt for pt in across if (pt[0] - target) * (best_y - target) < 0),
                        key=lambda pt: abs(pt[0] - target))
            status = STATUS_STALLED
            message = (f"the search stalled: rho_d = {target:g} lies inside the ranges (runs gave {y_lo:.4g} to "
                       f"{y_hi:.4g}), but the windows shrank onto {at}, where max|rho| = {best_y:.6g}: {why}; {done}; "
                       f"rho_d lies between that point and the run at "
                       + ", ".join(f"{s} = {v:.4g}" for s, v in zip(names, other[1]))
                       + f" (max|rho| = {other[0]:.4g}): start from ranges around both")
        else:
            side = "above" if y_lo >= target else "below"
            message = (f"rho_d = {target:g} is out of reach inside the ranges: every run gave max|rho| {side} it; "
                       f"best {best_y:.6g} at {at}; {why}; {done}"
                       + (f"; widen the range of {', '.join(edge)}" if edge else ""))
    elif all_failed:
        message = (f"every run of experiment {len(history)} failed (see failed_runs); best max|rho| = "
                   f"{best_y:.6g} at {at}")
    else:
        message = (f"target rho_d = {target:g} not reached within {config.max_evaluations} evaluations; "
                   f"best max|rho| = {best_y:.6g} at {at}")
    if failed:
        message += f"; {len(failed)} run(s) failed with a numerical error (failed_runs)"
    return TaguchiResult(
        gains=best_gains,
        names=names,
        spectral_radius=best_y,
        target=target,
        tolerance=tol,
        converged=converged,
        status=status,
        message=message,
        evaluations=evaluations,
        iterations=tuple(history),
        array=oa.name,
        elapsed=time.perf_counter() - t0,
        config=config,
        failed_runs=tuple(failed),
    )


def _at_bound(value: float, bounds: tuple[float, float]) -> str:
    """``" (lower end)"``/``" (upper end)"`` when ``value`` sits at an end of its initial range, else ``""``."""
    eps = 1e-9 * (bounds[1] - bounds[0])
    if abs(value - bounds[0]) <= eps:
        return " (lower end)"
    if abs(value - bounds[1]) <= eps:
        return " (upper end)"
    return ""


def _check_responses(ys: Sequence[float], points: Sequence[tuple[float, ...]], names: Sequence[str]) -> None:
    for y, p in zip(ys, points):
        if not math.isfinite(y) or y < 0:
            at = ", ".join(f"{s} = {v:.6g}" for s, v in zip(names, p))
            raise ValueError(f"objective returned {y!r} at {at}")
