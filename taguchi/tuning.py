"""Iterative Taguchi tuning of the PD gains to a target Floquet multiplier.

The objective is the paper's Eq. (34): drive ``y(kp, kd) = max_i |rho_i|``
to the target ``rho_d``.  One *iteration* is one Taguchi experiment:

1. **Levels.** Each factor (``kp``, ``kd``) gets ``levels`` equally spaced
   values spanning its current range ``[lo, hi]`` (ends included).
2. **Array.** The runs are the rows of an orthogonal array with two columns
   of ``levels`` levels (default L9 for 3 levels; ``array=`` chooses
   another, e.g. ``"L25"`` with 5 levels).  The runs are independent and go
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
   the best point reached.

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
from typing import Any, Callable, Optional, Sequence

import numpy as np

from taguchi.analysis import TaguchiAnalysis, analyze
from taguchi.arrays import OrthogonalArray, array_for, get_array, to_design
from taguchi.sn import sn_target

__all__ = [
    "GainObjective",
    "TaguchiIteration",
    "TaguchiResult",
    "TuningConfig",
    "check_gain_range",
    "taguchi_tune",
    "STATUS_CONVERGED",
    "STATUS_BUDGET",
]

logger = logging.getLogger(__name__)

STATUS_CONVERGED = "converged"
STATUS_BUDGET = "budget exhausted"


class GainObjective:
    """``(kp, kd) -> max_i |rho_i|`` for a plant that accepts PD gains.

    Parameters
    ----------
    plant : object
        Has ``with_gains(kp, kd)`` returning a periodic matrix accepted by
        :func:`stability.floquet` (e.g. :class:`mbs_models.reduced.ReducedModel`
        or the Exudyn linearisation).  Must be picklable for process or Dask
        executors.
    floquet_options : dict
        Keyword arguments for :func:`stability.floquet`.  The default uses a
        fixed number of sub-intervals without step doubling (fast inside the
        loop); the final gains are re-checked by the caller with the default
        adaptive method.  A plant with ``spectral_measure(kp, kd)`` supplies
        its own response instead (the Exudyn link: the dominant multiplier of
        its damped modes).
    """

    def __init__(self, plant: Any, floquet_options: Optional[dict] = None) -> None:
        if not callable(getattr(plant, "with_gains", None)):
            raise ValueError("plant must provide with_gains(kp, kd)")
        self.plant = plant
        self.floquet_options = dict(floquet_options or {"n_steps": 256, "error_estimate": False})

    def __call__(self, gains: Sequence[float]) -> float:
        from stability import floquet

        kp, kd = float(gains[0]), float(gains[1])
        measure = getattr(self.plant, "spectral_measure", None)
        if callable(measure):  # the plant defines its own response (e.g. the Exudyn link)
            return float(measure(kp, kd))
        return floquet(self.plant.with_gains(kp, kd), **self.floquet_options).spectral_radius


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


@dataclass(frozen=True)
class TuningConfig:
    """Options of :func:`taguchi_tune`.

    Attributes
    ----------
    target : float
        ``rho_d`` > 0.
    kp_range, kd_range : (float, float)
        Initial ranges, ``0 <= lo < hi``.
    array : str, optional
        Orthogonal array name (``"L9"``, ``"L16"``, ``"L25"``, ...); default
        the smallest array with two columns of ``levels`` levels.
    levels : int
        Levels per factor when ``array`` is not given (default 3 -> L9).
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

    def __post_init__(self) -> None:
        if not (isinstance(self.target, (int, float)) and math.isfinite(self.target) and self.target > 0):
            raise ValueError(f"target rho_d must be finite and > 0, got {self.target!r}")
        for name in ("kp_range", "kd_range"):
            object.__setattr__(self, name, check_gain_range(getattr(self, name), name))
        if isinstance(self.levels, bool) or not isinstance(self.levels, int) or self.levels < 2:
            raise ValueError(f"levels must be an integer >= 2, got {self.levels!r}")
        if self.tolerance is not None and not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"tolerance must be finite and > 0, got {self.tolerance!r}")
        if isinstance(self.max_evaluations, bool) or not isinstance(self.max_evaluations, int) or self.max_evaluations < 1:
            raise ValueError(f"max_evaluations must be a positive integer, got {self.max_evaluations!r}")
        if not (0 < self.shrink < 1):
            raise ValueError(f"shrink must be in (0, 1), got {self.shrink!r}")

    @property
    def effective_tolerance(self) -> float:
        """The stopping tolerance (``1e-3 rho_d`` unless given)."""
        return self.tolerance if self.tolerance is not None else 1e-3 * self.target

    def orthogonal_array(self) -> OrthogonalArray:
        """The two-factor array used for every iteration."""
        if self.array is None:
            return array_for(2, self.levels)
        oa = get_array(self.array)
        for s in sorted(set(oa.levels), reverse=True):
            cols = oa.columns_with_levels(s)
            if len(cols) >= 2:
                return oa.subset(cols[:2])
        raise ValueError(f"array {self.array!r} has no two columns with equal level counts")


@dataclass(frozen=True)
class TaguchiIteration:
    """One Taguchi experiment of the tuning history."""

    index: int
    kp_range: tuple[float, float]
    kd_range: tuple[float, float]
    kp_levels: tuple[float, ...]
    kd_levels: tuple[float, ...]
    design: tuple[tuple[float, float], ...]
    responses: tuple[float, ...]
    sn_ratios: tuple[float, ...]
    analysis: TaguchiAnalysis
    best_levels: tuple[int, int]
    predicted_sn: float
    confirmation_gains: tuple[float, float]
    confirmation_response: float
    confirmation_sn: float
    incumbent_gains: tuple[float, float]
    incumbent_response: float

    def __repr__(self) -> str:  # the design, responses and ANOVA are in to_dict(); keep a REPL readable
        return (f"TaguchiIteration(index={self.index}, kp_range=({self.kp_range[0]:.6g}, {self.kp_range[1]:.6g}), "
                f"kd_range=({self.kd_range[0]:.6g}, {self.kd_range[1]:.6g}), runs={len(self.design)}, "
                f"incumbent=(kp={self.incumbent_gains[0]:.6g}, kd={self.incumbent_gains[1]:.6g}, "
                f"max|rho|={self.incumbent_response:.6g}))")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return {
            "index": self.index,
            "kp_range": list(self.kp_range),
            "kd_range": list(self.kd_range),
            "kp_levels": list(self.kp_levels),
            "kd_levels": list(self.kd_levels),
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
                "kp": self.confirmation_gains[0],
                "kd": self.confirmation_gains[1],
                "spectral_radius": self.confirmation_response,
                "sn": self.confirmation_sn,
            },
            "incumbent": {
                "kp": self.incumbent_gains[0],
                "kd": self.incumbent_gains[1],
                "spectral_radius": self.incumbent_response,
            },
        }


@dataclass(frozen=True)
class TaguchiResult:
    """Outcome of :func:`taguchi_tune`.

    Attributes
    ----------
    kp, kd : float
        The best gains found.
    spectral_radius : float
        ``max|rho|`` at those gains (as evaluated inside the loop).
    target, tolerance : float
    converged : bool
    status : str
        ``"converged"`` or ``"budget exhausted"``.
    message : str
    evaluations : int
        Floquet evaluations used.
    iterations : tuple of TaguchiIteration
        The full history.
    array : str
        The orthogonal array used.
    elapsed : float
        Wall time in s.
    """

    kp: float
    kd: float
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

    def __repr__(self) -> str:  # one line: the history is summarised, not printed (see ``iterations``)
        return (f"TaguchiResult(kp={self.kp:.6g}, kd={self.kd:.6g}, spectral_radius={self.spectral_radius:.6g}, "
                f"target={self.target:g}, status={self.status!r}, evaluations={self.evaluations}, "
                f"iterations=<{len(self.iterations)} TaguchiIteration>, array={self.array!r}, "
                f"elapsed={self.elapsed:.3g} s)")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``iterations`` is the history)."""
        return {
            "kp": self.kp,
            "kd": self.kd,
            "spectral_radius": self.spectral_radius,
            "target": self.target,
            "tolerance": self.tolerance,
            "converged": self.converged,
            "status": self.status,
            "message": self.message,
            "evaluations": self.evaluations,
            "array": self.array,
            "elapsed": self.elapsed,
            "iterations": [it.to_dict() for it in self.iterations],
        }


def _levels(rng: tuple[float, float], n: int) -> np.ndarray:
    return np.linspace(rng[0], rng[1], n)


def _recentre(centre: float, width: float, bounds: tuple[float, float]) -> tuple[float, float]:
    """A window of ``width`` centred on ``centre``, shifted (not cut) to stay inside ``bounds``."""
    lo = max(bounds[0], centre - width / 2)
    hi = lo + width
    if hi > bounds[1]:
        hi = bounds[1]
        lo = max(bounds[0], hi - width)
    return (lo, hi)


def _evaluate(fn: Callable, points: list, executor: Optional[cf.Executor]) -> list[float]:
    if executor is None:
        return [float(fn(p)) for p in points]
    return [float(v) for v in executor.map(fn, points)]


def taguchi_tune(
    objective: Callable[[Sequence[float]], float],
    config: TuningConfig = TuningConfig(),
    *,
    executor: Optional[cf.Executor] = None,
    progress: bool = False,
) -> TaguchiResult:
    """Tune ``(kp, kd)`` so that ``objective(kp, kd) = max|rho|`` reaches ``config.target``.

    Parameters
    ----------
    objective : callable
        ``(kp, kd) -> max_i |rho_i|`` (e.g. :class:`GainObjective`); must be
        picklable when ``executor`` is a process pool or Dask.
    config : TuningConfig
    executor : concurrent.futures.Executor, optional
        Runs the array's rows; default serial in this process.
    progress : bool
        Show a tqdm bar over iterations.

    Returns
    -------
    TaguchiResult
        Never raises for an unreachable target: the status says
        ``"budget exhausted"`` and the best point reached is returned.

    Raises
    ------
    ValueError
        If the objective returns NaN/inf or a negative value.
    """
    t0 = time.perf_counter()
    oa = config.orthogonal_array()
    n_runs = oa.n_runs
    tol = config.effective_tolerance
    target = config.target
    kp_rng, kd_rng = config.kp_range, config.kd_range
    evaluations = 0
    history: list[TaguchiIteration] = []
    best_gains: Optional[tuple[float, float]] = None
    best_y = math.inf

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=config.max_evaluations, desc=f"Taguchi rho_d={target:g}", unit="eval", leave=False)
    try:
        while evaluations + n_runs + 1 <= config.max_evaluations:
            kp_lv = _levels(kp_rng, oa.levels[0])
            kd_lv = _levels(kd_rng, oa.levels[1])
            design = to_design(oa, [kp_lv.tolist(), kd_lv.tolist()])
            points = [(float(a), float(b)) for a, b in design]
            ys = _evaluate(objective, points, executor)
            _check_responses(ys, points)
            sn = np.array([sn_target(y, target) for y in ys])
            result = analyze(oa, sn, factor_names=("kp", "kd"))
            lv = result.best_levels
            conf = (float(kp_lv[lv[0]]), float(kd_lv[lv[1]]))
            y_conf = float(objective(conf))  # one run: no point shipping it to a worker
            _check_responses([y_conf], [conf])
            evaluations += n_runs + 1
            if bar is not None:
                bar.update(n_runs + 1)
            for p, y in list(zip(points, ys)) + [(conf, y_conf)]:
                if abs(y - target) < abs(best_y - target):
                    best_y, best_gains = y, p
            assert best_gains is not None
            history.append(
                TaguchiIteration(
                    index=len(history),
                    kp_range=kp_rng,
                    kd_range=kd_rng,
                    kp_levels=tuple(kp_lv.tolist()),
                    kd_levels=tuple(kd_lv.tolist()),
                    design=tuple(points),
                    responses=tuple(ys),
                    sn_ratios=tuple(sn.tolist()),
                    analysis=result,
                    best_levels=(int(lv[0]), int(lv[1])),
                    predicted_sn=float(result.predicted_sn),
                    confirmation_gains=conf,
                    confirmation_response=y_conf,
                    confirmation_sn=float(sn_target(y_conf, target)),
                    incumbent_gains=best_gains,
                    incumbent_response=best_y,
                )
            )
            logger.debug(
                "iteration %d: kp in %s, kd in %s -> best (%.5g, %.5g) rho=%.6g",
                len(history), kp_rng, kd_rng, best_gains[0], best_gains[1], best_y,
            )
            if abs(best_y - target) <= tol:
                break
            kp_rng = _recentre(best_gains[0], (kp_rng[1] - kp_rng[0]) * config.shrink, config.kp_range)
            kd_rng = _recentre(best_gains[1], (kd_rng[1] - kd_rng[0]) * config.shrink, config.kd_range)
    finally:
        if bar is not None:
            bar.close()

    if best_gains is None:
        raise ValueError(
            f"max_evaluations = {config.max_evaluations} is smaller than one experiment "
            f"({n_runs} runs + 1 confirmation with {oa.name})"
        )
    converged = abs(best_y - target) <= tol
    status = STATUS_CONVERGED if converged else STATUS_BUDGET
    message = (
        f"|max|rho| - rho_d| = {abs(best_y - target):.2e} <= {tol:.2e} after {evaluations} evaluations"
        if converged
        else f"target rho_d = {target:g} not reached within {config.max_evaluations} evaluations; "
        f"best max|rho| = {best_y:.6g} at kp = {best_gains[0]:.6g}, kd = {best_gains[1]:.6g}"
    )
    return TaguchiResult(
        kp=best_gains[0],
        kd=best_gains[1],
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
    )


def _check_responses(ys: Sequence[float], points: Sequence[tuple[float, float]]) -> None:
    for y, p in zip(ys, points):
        if not math.isfinite(y) or y < 0:
            raise ValueError(f"objective returned {y!r} at kp = {p[0]:.6g}, kd = {p[1]:.6g}")
