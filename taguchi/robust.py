"""Robust parameter design: an inner array of gains crossed with an outer array of noise factors.

Taguchi's crossed-array experiment (Phadke 1989, Ch. 5-6): every run of the
*inner* (control) array -- the PD gains -- is repeated at every run of the
*outer* (noise) array -- e.g. payload, frequency and stiffness within their
uncertainty ranges -- and the S/N ratio of a gain setting is computed over
its outer responses.  The iteration around it is the one of
:func:`taguchi.tuning.taguchi_tune` (levels over the current ranges, response
table of the S/N ratios, confirmation run at the best levels, incumbent =
best S/N so far, re-centre and shrink), except that there is no single
response to drive to a target: the loop maximises the S/N and stops when the
ranges have shrunk to ``xtol`` of their initial widths, after
``max_iterations`` experiments, or when the budget is spent.

Which S/N ratio (``RobustConfig.sn``)
-------------------------------------
``"target"`` (default): ``eta = -10 log10 mean_j (y_j - rho_d)^2`` over the
outer runs ``j`` -- Taguchi's quadratic loss about the target, i.e.
``(ybar - rho_d)^2 + s^2``: it trades the miss of the design target against
the spread caused by the noise, and it keeps ``rho_d`` the design target
as in the nominal tuning (paper Eq. 34).  ``"smaller"`` (smaller-the-better,
``-10 log10 mean y_j^2``) is available, but for PD gains it rewards ever
larger gains (``max|rho|`` falls with ``kd`` over most of the range), so it
tunes to the edge of the gain ranges rather than to a design target.

Failed runs
-----------
The contract of :func:`taguchi.tuning.taguchi_tune` ("Failed runs"): an
(inner, outer) run whose objective raises one of
:data:`taguchi.tuning.RUN_FAILURES` is recorded (``failures`` of its
iteration, ``failed_runs`` of the result: iteration, inner ``run`` index or
``"confirmation"``, ``outer_run`` index, gains, noise, error), its response is
NaN (``null`` in JSON), and its inner run scores the worst S/N of the
experiment's inner runs without a failure; it never becomes the incumbent
(a failed confirmation has S/N NaN).  When every inner run of an experiment
has a failure the tuning stops: with ``ArithmeticError`` if there is no
incumbent yet, else with status ``"runs failed"``.

Everything here is model-free: the objective is any callable
``(gains, noise) -> y`` with ``noise`` a mapping from noise-factor names to
values.

References
----------
.. [1] M. S. Phadke, *Quality Engineering Using Robust Design*, Prentice
   Hall, 1989, Ch. 5 (S/N ratios), Ch. 6 (crossed arrays, noise factors).
.. [2] G. Taguchi, *System of Experimental Design*, UNIPUB/Kraus, 1987.
"""
from __future__ import annotations

import concurrent.futures as cf
import itertools
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from taguchi.analysis import TaguchiAnalysis, analyze
from taguchi.arrays import OrthogonalArray, array_for, get_array, to_design
from taguchi.sn import sn_ratio
from stability.gains import Gains
from taguchi.tuning import LOOP_FLOQUET_OPTIONS, STATUS_FAILED, TuningConfig, _Guarded, plant_response, recentre

__all__ = [
    "NoiseFactor",
    "RobustConfig",
    "RobustIteration",
    "RobustResult",
    "WorstCase",
    "PlantNoiseObjective",
    "noise_grid",
    "robust_tune",
    "worst_case",
    "ROBUST_SN",
]

logger = logging.getLogger(__name__)

#: S/N ratios a robust design may use (see the module docstring).
ROBUST_SN = ("target", "smaller")


@dataclass(frozen=True)
class NoiseFactor:
    """A noise factor: name, uncertainty range and nominal value.

    The outer array uses ``levels`` equally spaced values over ``[low, high]``
    (ends included); ``nominal`` is the value of the nominal design.
    """

    name: str
    low: float
    high: float
    nominal: float
    levels: int = 3

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"noise factor name must be a non-empty string, got {self.name!r}")
        for key in ("low", "high", "nominal"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"noise factor {self.name}: {key} must be a finite number, got {v!r}")
            object.__setattr__(self, key, float(v))
        if not self.low < self.high:
            raise ValueError(f"noise factor {self.name}: range is empty or inverted ({self.low}, {self.high})")
        if not self.low <= self.nominal <= self.high:
            raise ValueError(f"noise factor {self.name}: nominal {self.nominal} outside [{self.low}, {self.high}]")
        if isinstance(self.levels, bool) or not isinstance(self.levels, int) or self.levels < 2:
            raise ValueError(f"noise factor {self.name}: levels must be an integer >= 2, got {self.levels!r}")

    def values(self, n: Optional[int] = None) -> np.ndarray:
        """``n`` (default ``levels``) equally spaced values over ``[low, high]``."""
        return np.linspace(self.low, self.high, self.levels if n is None else n)


@dataclass(frozen=True)
class RobustConfig:
    """Options of :func:`robust_tune`.

    Attributes
    ----------
    tuning : TuningConfig
        Inner array: target ``rho_d``, gain ranges and names, levels, inner
        array name, shrink factor and the evaluation budget (counting every
        inner x outer run).
    noise : tuple of NoiseFactor
        The noise factors (at least one, distinct names, equal level counts).
    outer_array : str, optional
        Orthogonal array of the noise factors; default the smallest with one
        column per noise factor (three factors at 3 levels: L9).
    sn : {"target", "smaller"}
        S/N ratio over the outer runs (module docstring).
    max_iterations : int
        Experiments at most.
    xtol : float
        Stop when every range is narrower than ``xtol`` times its initial width.
    """

    tuning: TuningConfig = field(default_factory=TuningConfig)
    noise: tuple[NoiseFactor, ...] = ()
    outer_array: Optional[str] = None
    sn: str = "target"
    max_iterations: int = 12
    xtol: float = 1e-3

    def __post_init__(self) -> None:
        if not isinstance(self.tuning, TuningConfig):
            raise ValueError(f"tuning must be a TuningConfig, got {type(self.tuning).__name__}")
        noise = tuple(self.noise)
        if not noise or not all(isinstance(n, NoiseFactor) for n in noise):
            raise ValueError("noise must be a non-empty sequence of NoiseFactor")
        names = [n.name for n in noise]
        if len(set(names)) != len(names):
            raise ValueError(f"noise factor names must be distinct, got {names}")
        if len({n.levels for n in noise}) != 1:
            raise ValueError(f"noise factors must have equal level counts, got {[n.levels for n in noise]}")
        object.__setattr__(self, "noise", noise)
        if self.sn not in ROBUST_SN:
            raise ValueError(f"robust S/N must be one of {', '.join(ROBUST_SN)}, got {self.sn!r}")
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, int) or self.max_iterations < 1:
            raise ValueError(f"max_iterations must be a positive integer, got {self.max_iterations!r}")
        if not (math.isfinite(self.xtol) and 0 < self.xtol < 1):
            raise ValueError(f"xtol must be in (0, 1), got {self.xtol!r}")

    @property
    def noise_names(self) -> tuple[str, ...]:
        return tuple(n.name for n in self.noise)

    @property
    def nominal_noise(self) -> dict[str, float]:
        """The nominal value of every noise factor."""
        return {n.name: n.nominal for n in self.noise}

    def outer(self) -> OrthogonalArray:
        """The outer (noise) array: one column per noise factor."""
        k, s = len(self.noise), self.noise[0].levels
        if self.outer_array is None:
            return array_for(k, s)
        oa = get_array(self.outer_array)
        cols = oa.columns_with_levels(s)
        if len(cols) < k:
            raise ValueError(f"outer array {self.outer_array!r} has no {k} columns of {s} levels")
        return oa.subset(cols[:k])

    def outer_runs(self) -> tuple[dict[str, float], ...]:
        """The noise values of every outer run."""
        design = to_design(self.outer(), [n.values().tolist() for n in self.noise])
        return tuple({n.name: float(v) for n, v in zip(self.noise, row)} for row in design)

    def score(self, ys: Sequence[float]) -> float:
        """S/N of one gain setting over its outer responses."""
        if self.sn == "target":
            return sn_ratio(ys, "target", self.tuning.target)
        return sn_ratio(ys, self.sn)


@dataclass(frozen=True)
class RobustIteration:
    """One crossed-array experiment of the robust tuning history."""

    index: int
    ranges: tuple[tuple[float, float], ...]
    factor_levels: tuple[tuple[float, ...], ...]
    design: tuple[tuple[float, ...], ...]
    responses: tuple[tuple[float, ...], ...]
    sn_ratios: tuple[float, ...]
    analysis: TaguchiAnalysis
    best_levels: tuple[int, ...]
    confirmation_gains: tuple[float, ...]
    confirmation_responses: tuple[float, ...]
    confirmation_sn: float
    incumbent_gains: tuple[float, ...]
    incumbent_sn: float
    failures: tuple[dict, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index, "ranges": [list(r) for r in self.ranges],
            "factor_levels": [list(v) for v in self.factor_levels],
            "design": [list(r) for r in self.design], "responses": [list(r) for r in self.responses],
            "sn_ratios": list(self.sn_ratios), "best_levels": list(self.best_levels),
            "contribution_percent": list(self.analysis.anova.contribution_percent),
            "confirmation": {"gains": list(self.confirmation_gains),
                             "responses": list(self.confirmation_responses), "sn": self.confirmation_sn},
            "incumbent": {"gains": list(self.incumbent_gains), "sn": self.incumbent_sn},
            "failures": [dict(f) for f in self.failures],
        }


@dataclass(frozen=True)
class RobustResult:
    """Outcome of :func:`robust_tune`.

    Attributes
    ----------
    gains, names : tuple
        The most robust gains found and the factor names.
    sn : float
        Their S/N over the outer array (dB).
    responses : tuple of float
        Their responses at the outer runs.
    outer_runs : tuple of dict
        The noise values of the outer runs.
    evaluations : int
        Objective evaluations (inner x outer runs + confirmations).
    iterations : tuple of RobustIteration
    status, message : str
        ``"converged"`` (ranges below ``xtol``), ``"iteration limit"``,
        ``"budget exhausted"`` or ``"runs failed"`` (every inner run of an experiment had a failed run).
    inner_array, outer_array : str
    elapsed : float
    failed_runs : tuple of dict
        Every (inner, outer) run whose objective raised one of :data:`taguchi.tuning.RUN_FAILURES`:
        ``iteration``, ``run`` (inner index or ``"confirmation"``), ``outer_run``, ``gains``, ``noise``,
        ``error`` (module docstring, "Failed runs").
    """

    gains: tuple[float, ...]
    names: tuple[str, ...]
    sn: float
    responses: tuple[float, ...]
    outer_runs: tuple[dict[str, float], ...]
    evaluations: int
    iterations: tuple[RobustIteration, ...]
    status: str
    message: str
    inner_array: str
    outer_array: str
    elapsed: float
    config: RobustConfig = field(repr=False, default_factory=lambda: RobustConfig(
        noise=(NoiseFactor("z", -1.0, 1.0, 0.0),)))
    failed_runs: tuple[dict, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {s: float(v) for s, v in zip(self.names, self.gains)}
        out.update({
            "names": list(self.names), "gains": list(self.gains), "sn": self.sn,
            "responses": list(self.responses), "outer_runs": [dict(r) for r in self.outer_runs],
            "evaluations": self.evaluations, "status": self.status, "message": self.message,
            "inner_array": self.inner_array, "outer_array": self.outer_array, "elapsed": self.elapsed,
            "sn_kind": self.config.sn, "target": self.config.tuning.target,
            "noise": [{"name": n.name, "low": n.low, "high": n.high, "nominal": n.nominal, "levels": n.levels}
                      for n in self.config.noise],
            "failed_runs": [dict(f) for f in self.failed_runs],
            "iterations": [it.to_dict() for it in self.iterations],
        })
        return out


class _Crossed:
    """``(gains, noise) -> y`` bound to one outer run, picklable for executors."""

    def __init__(self, objective: Callable, noise: Mapping[str, float]) -> None:
        self.objective, self.noise = objective, dict(noise)

    def __call__(self, gains: Sequence[float]) -> float:
        return float(self.objective(tuple(gains), self.noise))


def _evaluate_crossed(objective, points, outer, executor, *, guarded: bool = False):
    """Responses of every inner point at every outer run, shape ``(len(points), len(outer))``.

    With ``guarded`` returns ``(y, errors)``: a run raising one of :data:`taguchi.tuning.RUN_FAILURES`
    has response NaN and ``errors[(i, j)] = "ErrorType: message"``; without it any error propagates.
    """
    tasks = [(p, o) for p in points for o in outer]
    fn = _Guarded(_Pair(objective)) if guarded else _Unguarded(_Pair(objective))
    runs = [fn(t) for t in tasks] if executor is None else list(executor.map(fn, tasks))
    y = np.array([v for v, _ in runs]).reshape(len(points), len(outer))
    errors = {divmod(k, len(outer)): err for k, (_, err) in enumerate(runs) if err is not None}
    failed = np.array([err is not None for _, err in runs], dtype=bool).reshape(y.shape)
    bad = (~np.isfinite(y) | (y < 0)) & ~failed
    if np.any(bad):
        i, j = np.argwhere(bad)[0]
        raise ValueError(f"objective returned {y[i, j]!r} at gains {points[i]} and noise {outer[j]}")
    return (y, errors) if guarded else y


class _Pair:
    """``(gains, noise) -> objective(gains, noise)`` on one task tuple (picklable)."""

    def __init__(self, objective: Callable) -> None:
        self.objective = objective

    def __call__(self, task: tuple) -> float:
        gains, noise = task
        return float(self.objective(gains, noise))


class _Unguarded:
    """``task -> (response, None)``: :class:`taguchi.tuning._Guarded`'s shape, every error propagating."""

    def __init__(self, fn: Callable) -> None:
        self.fn = fn

    def __call__(self, task: tuple) -> tuple[float, None]:
        return float(self.fn(task)), None


def robust_tune(
    objective: Callable[[Sequence[float], Mapping[str, float]], float],
    config: RobustConfig,
    *,
    executor: Optional[cf.Executor] = None,
) -> RobustResult:
    """Maximise the S/N over the outer (noise) array by iterated crossed-array experiments.

    Parameters
    ----------
    objective : callable
        ``(gains, noise) -> y`` (``y = max|rho|``), ``gains`` in the order of
        ``config.tuning.names``, ``noise`` a dict ``{name: value}``; picklable
        for process or Dask executors.
    config : RobustConfig
    executor : concurrent.futures.Executor, optional
        Runs the inner x outer runs of an experiment; default serial.

    Returns
    -------
    RobustResult

    Raises
    ------
    ValueError
        If the objective returns NaN/inf or a negative value, or the budget
        is smaller than one experiment.
    ArithmeticError
        If every inner run of the first experiment has a failed run (one of
        :data:`taguchi.tuning.RUN_FAILURES`); single failed runs are recorded
        instead (module docstring, "Failed runs").
    """
    t0 = time.perf_counter()
    tcfg = config.tuning
    inner = tcfg.orthogonal_array()
    outer_oa = config.outer()
    outer = config.outer_runs()
    names = tuple(tcfg.names)  # type: ignore[arg-type]
    bounds = tcfg.factor_ranges
    rngs = tuple(bounds)
    cost = (inner.n_runs + 1) * len(outer)
    if cost > tcfg.max_evaluations:
        raise ValueError(
            f"max_evaluations = {tcfg.max_evaluations} is smaller than one crossed experiment "
            f"({inner.n_runs} + 1 inner runs x {len(outer)} outer runs = {cost})"
        )
    evaluations = 0
    history: list[RobustIteration] = []
    best_gains: Optional[tuple[float, ...]] = None
    best_sn, best_ys = -math.inf, ()
    failed_runs: list[dict] = []
    status, message = "iteration limit", f"stopped after {config.max_iterations} experiments"

    def record(run, point, errors) -> list[dict]:
        return [{"iteration": len(history), "run": run(i), "outer_run": j, "gains": list(point(i)),
                 "noise": dict(outer[j]), "error": err} for (i, j), err in sorted(errors.items())]

    while True:
        if evaluations + cost > tcfg.max_evaluations:
            status, message = "budget exhausted", f"budget of {tcfg.max_evaluations} evaluations spent"
            break
        lv_values = [np.linspace(r[0], r[1], s) for r, s in zip(rngs, inner.levels)]
        points = [tuple(float(x) for x in row) for row in to_design(inner, [v.tolist() for v in lv_values])]
        y, errors = _evaluate_crossed(objective, points, outer, executor, guarded=True)
        logger.info("robust experiment %d: %d inner x %d outer runs evaluated (%d of %d evaluations)",
                    len(history) + 1, inner.n_runs, len(outer), evaluations + inner.n_runs * len(outer),
                    tcfg.max_evaluations)
        fails = record(lambda i: i, lambda i: points[i], errors)
        good = [i for i in range(len(points)) if not any((i, j) in errors for j in range(len(outer)))]
        if not good:
            evaluations += inner.n_runs * len(outer)
            failed_runs.extend(fails)
            if best_gains is None:
                f = fails[0]
                raise ArithmeticError(
                    f"every inner run of the first robust experiment failed ({inner.n_runs} inner x "
                    f"{len(outer)} outer runs); the first at gains {f['gains']}, noise {f['noise']}: {f['error']}")
            logger.warning("every inner run of robust experiment %d failed: stopping with the best point so far",
                           len(history))
            status = STATUS_FAILED
            message = f"every inner run of experiment {len(history)} had a failed run (see failed_runs)"
            break
        sn_good = {i: config.score(y[i]) for i in good}
        worst = min(sn_good.values())  # an inner run with a failed run scores as the worst of its experiment
        sn = np.array([sn_good.get(i, worst) for i in range(len(points))])
        result = analyze(inner, sn, factor_names=names)
        conf = tuple(float(v[k]) for v, k in zip(lv_values, result.best_levels))
        y_conf, conf_errors = _evaluate_crossed(objective, [conf], outer, None, guarded=True)
        y_conf = y_conf[0]
        fails += record(lambda i: "confirmation", lambda i: conf, conf_errors)
        sn_conf = math.nan if conf_errors else config.score(y_conf)
        failed_runs.extend(fails)
        evaluations += cost
        for i, (p, s, row) in enumerate(list(zip(points, sn, y)) + [(conf, sn_conf, y_conf)]):
            if (i < len(points) and i not in sn_good) or not math.isfinite(s):  # a failed run
                continue
            if s > best_sn:
                best_sn, best_gains, best_ys = float(s), p, tuple(float(v) for v in row)
        assert best_gains is not None
        history.append(RobustIteration(
            index=len(history), ranges=rngs, factor_levels=tuple(tuple(v.tolist()) for v in lv_values),
            design=tuple(points), responses=tuple(tuple(r.tolist()) for r in y), sn_ratios=tuple(sn.tolist()),
            analysis=result, best_levels=tuple(int(k) for k in result.best_levels),
            confirmation_gains=conf, confirmation_responses=tuple(y_conf.tolist()), confirmation_sn=float(sn_conf),
            incumbent_gains=best_gains, incumbent_sn=best_sn, failures=tuple(fails),
        ))
        logger.debug("robust iteration %d: best %s S/N %.3f dB", len(history), best_gains, best_sn)
        rngs = tuple(recentre(c, (r[1] - r[0]) * tcfg.shrink, b) for c, r, b in zip(best_gains, rngs, bounds))
        if all((r[1] - r[0]) <= config.xtol * (b[1] - b[0]) for r, b in zip(rngs, bounds)):
            status = "converged"
            message = f"ranges below {config.xtol:g} of their initial widths after {evaluations} evaluations"
            break
        if len(history) >= config.max_iterations:
            break
    if failed_runs:
        message += f"; {len(failed_runs)} run(s) failed with a numerical error (failed_runs)"
    return RobustResult(
        gains=best_gains, names=names, sn=best_sn, responses=best_ys, outer_runs=outer,
        evaluations=evaluations, iterations=tuple(history), status=status, message=message,
        inner_array=inner.name, outer_array=outer_oa.name, elapsed=time.perf_counter() - t0, config=config,
        failed_runs=tuple(failed_runs),
    )


def noise_grid(noise: Sequence[NoiseFactor], points: int = 9) -> tuple[dict[str, float], ...]:
    """Full-factorial grid of ``points`` equally spaced values per noise factor (ends included)."""
    if isinstance(points, bool) or not isinstance(points, int) or points < 2:
        raise ValueError(f"points must be an integer >= 2, got {points!r}")
    axes = [n.values(points) for n in noise]
    return tuple({n.name: float(v) for n, v in zip(noise, combo)} for combo in itertools.product(*axes))


@dataclass(frozen=True)
class WorstCase:
    """A gain setting judged over a grid of noise values.

    Attributes
    ----------
    gains : tuple of float
    values : tuple of float
        ``y`` at every grid point.
    worst : float
        ``max`` of ``values``.
    worst_noise : dict
        The grid point where it occurs.
    nominal : float
        ``y`` at the nominal noise values.
    grid_size : int
    """

    gains: tuple[float, ...]
    values: tuple[float, ...]
    worst: float
    worst_noise: dict[str, float]
    nominal: float
    grid_size: int

    def to_dict(self) -> dict[str, Any]:
        return {"gains": list(self.gains), "worst": self.worst, "worst_noise": dict(self.worst_noise),
                "nominal": self.nominal, "grid_size": self.grid_size,
                "mean": float(np.mean(self.values)), "min": float(np.min(self.values))}


def worst_case(
    objective: Callable[[Sequence[float], Mapping[str, float]], float],
    gains: Sequence[float],
    grid: Sequence[Mapping[str, float]],
    nominal: Mapping[str, float],
    *,
    executor: Optional[cf.Executor] = None,
) -> WorstCase:
    """``max`` of ``objective(gains, noise)`` over ``grid`` (e.g. :func:`noise_grid`), and its nominal value."""
    g = tuple(float(v) for v in gains)
    vals = _evaluate_crossed(objective, [g], list(grid), executor)[0]
    k = int(np.argmax(vals))
    return WorstCase(gains=g, values=tuple(vals.tolist()), worst=float(vals[k]), worst_noise=dict(grid[k]),
                     nominal=float(objective(g, dict(nominal))), grid_size=len(grid))


class PlantNoiseObjective:
    """``(gains, noise) -> max|rho|`` for plants built per noise value.

    Parameters
    ----------
    factory : callable
        ``noise -> plant``, a :class:`stability.gains.Plant` or
        :class:`stability.gains.MeasuredPlant` (the response as in
        :class:`taguchi.tuning.GainObjective`); picklable for process executors.
    floquet_options : dict, optional
        As in :class:`taguchi.tuning.GainObjective`.
    """

    def __init__(self, factory: Callable[[Mapping[str, float]], Any], floquet_options: Optional[dict] = None) -> None:
        self.factory = factory
        self.floquet_options = dict(floquet_options or LOOP_FLOQUET_OPTIONS)

    def __call__(self, gains: Sequence[float], noise: Mapping[str, float]) -> float:
        return plant_response(self.factory(noise), Gains.from_interleaved(gains), self.floquet_options)
