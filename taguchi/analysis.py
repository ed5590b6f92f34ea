"""Analysis of a Taguchi experiment on S/N ratios, laid out as Minitab does.

* :func:`response_table` -- mean S/N at each level of each factor, the
  delta (max - min of those means) and the rank of the deltas;
* :func:`anova` -- sums of squares of the factors on the S/N ratios and
  their percentage contributions, with the remainder as error;
* :func:`best_levels` -- the level with the largest mean S/N per factor;
* :func:`predict_sn` -- the additive-model prediction at chosen levels;
* :func:`is_constant` -- whether an experiment's S/N ratios are all equal (nothing to analyse);
* :func:`analyze` -- all four at once (:class:`TaguchiAnalysis`).

Levels are 0-based indices everywhere (Minitab prints them 1-based).

References
----------
.. [1] M. S. Phadke, *Quality Engineering Using Robust Design*,
   Prentice Hall, 1989, Ch. 3 (main effects, ANOVA, additive-model
   prediction) and Ch. 4.
.. [2] P. J. Ross, *Taguchi Techniques for Quality Engineering*, 2nd ed.,
   McGraw-Hill, 1996 (ANOVA and percent contribution).
.. [3] D. C. Montgomery, *Design and Analysis of Experiments*, 8th ed.,
   Wiley, 2013, Ch. 12.
.. [4] Minitab, "Analyze Taguchi Design" (response tables for S/N ratios,
   delta and rank).
"""

from __future__ import annotations

import logging
import string
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from .arrays import OrthogonalArray, check_orthogonal_array, level_counts

__all__ = [
    "AnovaTable",
    "ResponseTable",
    "TaguchiAnalysis",
    "analyze",
    "anova",
    "best_levels",
    "is_constant",
    "predict_sn",
    "response_table",
]

logger = logging.getLogger(__name__)

#: Relative size (of the total sum of squares) below which the error sum of
#: squares, a difference of nearly equal sums, is round-off and set to 0.
#: 1e3 machine epsilons leaves room for the O(runs) rounding of the sums.
SS_ROUNDOFF_RTOL: float = 1e3 * float(np.finfo(float).eps)


@dataclass(frozen=True)
class ResponseTable:
    """Response table for S/N ratios (Minitab's "Response Table for Signal to Noise Ratios").

    Attributes
    ----------
    factors : tuple of str
        Factor names, one per analysed column.
    columns : tuple of int
        The array columns the factors sit in.
    levels : tuple of int
        Number of levels of each factor.
    level_means : tuple of tuple of float
        ``level_means[j][k]``: mean S/N over the runs with factor ``j`` at
        level ``k`` (0-based).
    delta : tuple of float
        ``max_k level_means[j][k] - min_k level_means[j][k]``.
    rank : tuple of int
        1 for the largest delta; ties share the order of the factors.
    overall_mean : float
        Mean S/N over all runs.
    sn : tuple of float
        The S/N ratios analysed, one per run (input kept on the result).
    design : tuple of tuple of int
        The 0-based levels of the analysed columns, run by run (input kept).
    """

    factors: tuple[str, ...]
    columns: tuple[int, ...]
    levels: tuple[int, ...]
    level_means: tuple[tuple[float, ...], ...]
    delta: tuple[float, ...]
    rank: tuple[int, ...]
    overall_mean: float
    sn: tuple[float, ...]
    design: tuple[tuple[int, ...], ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dictionary."""
        return asdict(self)

    def format(self, precision: int = 3) -> str:
        """Minitab-style text table: rows Level 1..k, Delta, Rank; one column per factor."""
        width = max(10, *(len(f) + 2 for f in self.factors))
        head = "Level".ljust(7) + "".join(f.rjust(width) for f in self.factors)
        rows = [head]
        for k in range(max(self.levels)):
            cells = [
                f"{m[k]:.{precision}f}" if k < len(m) else "" for m in self.level_means
            ]
            rows.append(str(k + 1).ljust(7) + "".join(c.rjust(width) for c in cells))
        rows.append("Delta".ljust(7) + "".join(f"{d:.{precision}f}".rjust(width) for d in self.delta))
        rows.append("Rank".ljust(7) + "".join(str(r).rjust(width) for r in self.rank))
        return "\n".join(rows)


@dataclass(frozen=True)
class AnovaTable:
    """Analysis of variance of the S/N ratios with percentage contributions.

    Attributes
    ----------
    factors : tuple of str
        Factor names.
    dof : tuple of int
        Degrees of freedom of each factor, ``levels - 1``.
    sum_of_squares : tuple of float
        Factor sums of squares.
    mean_square : tuple of float
        ``sum_of_squares / dof``.
    f_ratio : tuple of float
        ``mean_square / error_mean_square``; NaN when the error has no
        degrees of freedom or a zero mean square.
    contribution_percent : tuple of float
        ``100 * sum_of_squares / total_sum_of_squares``; NaN if the total is 0.
    error_dof, error_sum_of_squares, error_mean_square, error_contribution_percent
        The remainder: ``total - sum(factors)``; ``error_mean_square`` is NaN
        when ``error_dof == 0``.
    total_dof : int
        ``runs - 1``.
    total_sum_of_squares : float
        ``sum_i (sn_i - mean)^2``.
    """

    factors: tuple[str, ...]
    dof: tuple[int, ...]
    sum_of_squares: tuple[float, ...]
    mean_square: tuple[float, ...]
    f_ratio: tuple[float, ...]
    contribution_percent: tuple[float, ...]
    error_dof: int
    error_sum_of_squares: float
    error_mean_square: float
    error_contribution_percent: float
    total_dof: int
    total_sum_of_squares: float

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary (NaN stays NaN; serialise with ``allow_nan``)."""
        return asdict(self)


@dataclass(frozen=True)
class TaguchiAnalysis:
    """Everything :func:`analyze` computes for one array of runs.

    Attributes
    ----------
    response_table : ResponseTable
    anova : AnovaTable
    best_levels : tuple of int
        Level (0-based) with the largest mean S/N, per factor.
    predicted_sn : float
        Additive-model S/N at ``best_levels``.
    """

    response_table: ResponseTable
    anova: AnovaTable
    best_levels: tuple[int, ...]
    predicted_sn: float

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary."""
        return asdict(self)


def is_constant(sn: npt.ArrayLike) -> bool:
    """Whether all S/N ratios of an experiment are equal (total sum of squares 0).

    Such an experiment carries no information about the factors: its main effects are all
    zero and the percentage contributions of :func:`anova` are undefined (NaN, with a
    ``RuntimeWarning``).  An iterative search uses this to stop instead of analysing it.
    """
    y = np.asarray(sn, dtype=float)
    return bool(y.size == 0 or float(np.sum((y - np.mean(y)) ** 2)) == 0.0)


def _default_names(n: int) -> tuple[str, ...]:
    letters = string.ascii_uppercase
    return tuple(letters[j] if j < len(letters) else f"X{j + 1}" for j in range(n))


def _inputs(
    oa: OrthogonalArray | npt.ArrayLike,
    sn: npt.ArrayLike,
    factor_names: Sequence[str] | None,
    columns: Sequence[int] | None,
) -> tuple[np.ndarray, tuple[int, ...], np.ndarray, tuple[str, ...], tuple[int, ...]]:
    """Validate and return (levels matrix of the factors, levels, sn, names, columns)."""
    if isinstance(oa, OrthogonalArray):
        full, full_levels = oa.matrix, oa.levels
    else:
        full = np.asarray(oa)
        if full.ndim != 2 or full.size == 0:
            raise ValueError(f"design must be a non-empty 2-D matrix of levels, got shape {full.shape}")
        full_levels = level_counts(full)
        full = np.asarray(full, dtype=np.int64)
    y = np.asarray(sn, dtype=float)
    if y.ndim != 1 or y.size == 0:
        raise ValueError(f"S/N ratios must be a non-empty 1-D array, got shape {y.shape}")
    if y.size != full.shape[0]:
        raise ValueError(f"{y.size} S/N ratios for an array of {full.shape[0]} runs")
    if not np.all(np.isfinite(y)):
        bad = np.flatnonzero(~np.isfinite(y)).tolist()
        raise ValueError(f"S/N ratios must be finite; runs {bad} are not ({y[bad].tolist()})")
    if columns is None:
        n = full.shape[1] if factor_names is None else len(factor_names)
        columns = range(n)
    cols = tuple(int(c) for c in columns)
    if not cols:
        raise ValueError("no factors to analyse")
    if len(set(cols)) != len(cols) or any(not 0 <= c < full.shape[1] for c in cols):
        raise ValueError(f"columns must be distinct indices in 0..{full.shape[1] - 1}, got {cols}")
    names = _default_names(len(cols)) if factor_names is None else tuple(str(f) for f in factor_names)
    if len(names) != len(cols):
        raise ValueError(f"{len(names)} factor names for {len(cols)} columns")
    if len(set(names)) != len(names):
        raise ValueError(f"factor names must be distinct, got {names}")
    design = full[:, cols]
    check_orthogonal_array(design)
    return design, tuple(full_levels[c] for c in cols), y, names, cols


def response_table(
    oa: OrthogonalArray | npt.ArrayLike,
    sn: npt.ArrayLike,
    factor_names: Sequence[str] | None = None,
    columns: Sequence[int] | None = None,
) -> ResponseTable:
    """Mean S/N per factor level, delta and rank.

    Parameters
    ----------
    oa : OrthogonalArray or array_like of int, shape (runs, columns)
        The array that was run (0-based levels).
    sn : array_like of float, shape (runs,)
        S/N ratio of each run (see :mod:`taguchi.sn`); must be finite.
    factor_names : sequence of str, optional
        Names of the factors; default ``'A', 'B', ...``.
    columns : sequence of int, optional
        Array column of each factor; default the first ``len(factor_names)``
        columns (all columns if no names are given).  Unused columns are
        left out of the table and their variation counts as error in
        :func:`anova`.

    Returns
    -------
    ResponseTable

    Raises
    ------
    ValueError
        Empty or non-finite S/N, length mismatch, bad columns, or analysed
        columns that are not balanced and pairwise orthogonal (their level
        means would be confounded).

    Maths
    -----
    With ``N`` runs, factor ``j`` at ``s_j`` levels, ``n_{jk} = N / s_j``
    runs at level ``k``:

    .. math::
        \\bar\\eta = \\frac1N \\sum_i \\eta_i, \\qquad
        m_{jk} = \\frac{1}{n_{jk}} \\sum_{i:\\,x_{ij} = k} \\eta_i, \\qquad
        \\Delta_j = \\max_k m_{jk} - \\min_k m_{jk}.

    References
    ----------
    Phadke (1989), Ch. 3 (main effects); Minitab, "Analyze Taguchi Design".
    """
    design, levels, y, names, cols = _inputs(oa, sn, factor_names, columns)
    means = tuple(
        tuple(float(np.mean(y[design[:, j] == k])) for k in range(s))
        for j, s in enumerate(levels)
    )
    delta = tuple(max(m) - min(m) for m in means)
    order = sorted(range(len(delta)), key=lambda j: (-delta[j], j))
    rank = [0] * len(delta)
    for r, j in enumerate(order, start=1):
        rank[j] = r
    return ResponseTable(
        factors=names,
        columns=cols,
        levels=levels,
        level_means=means,
        delta=delta,
        rank=tuple(rank),
        overall_mean=float(np.mean(y)),
        sn=tuple(float(v) for v in y),
        design=tuple(tuple(int(v) for v in row) for row in design),
    )


def anova(
    oa: OrthogonalArray | npt.ArrayLike,
    sn: npt.ArrayLike,
    factor_names: Sequence[str] | None = None,
    columns: Sequence[int] | None = None,
) -> AnovaTable:
    """ANOVA of the S/N ratios: sums of squares and percentage contributions.

    Parameters
    ----------
    oa, sn, factor_names, columns
        As in :func:`response_table`.

    Returns
    -------
    AnovaTable

    Raises
    ------
    ValueError
        As :func:`response_table`.

    Warns
    -----
    RuntimeWarning
        If all S/N ratios are equal (total sum of squares 0): contributions
        are then NaN.

    Maths
    -----
    .. math::
        SS_T = \\sum_i (\\eta_i - \\bar\\eta)^2, \\qquad
        SS_j = \\sum_k n_{jk} (m_{jk} - \\bar\\eta)^2, \\qquad
        SS_e = SS_T - \\sum_j SS_j,

        \\nu_j = s_j - 1, \\quad \\nu_T = N - 1, \\quad
        \\nu_e = \\nu_T - \\sum_j \\nu_j, \\qquad
        P_j = 100\\, SS_j / SS_T, \\quad P_e = 100\\, SS_e / SS_T.

    ``P_j`` is the plain ratio of sums of squares (not Ross's "pure" sum of
    squares ``SS_j - \\nu_j V_e``), so factor and error contributions add up
    to 100 %.  ``SS_e`` is set to 0 when it is round-off
    (``|SS_e| <= SS_ROUNDOFF_RTOL * SS_T``).

    References
    ----------
    Phadke (1989), Ch. 3 (ANOVA for orthogonal arrays); Ross (1996)
    (percent contribution); Montgomery (2013), Ch. 12.
    """
    table = response_table(oa, sn, factor_names, columns)
    y = np.asarray(table.sn)
    n_runs = y.size
    ss_total = float(np.sum((y - table.overall_mean) ** 2))
    ss, dof = [], []
    for m, s in zip(table.level_means, table.levels):
        n_per_level = n_runs // s
        ss.append(float(n_per_level * np.sum((np.asarray(m) - table.overall_mean) ** 2)))
        dof.append(s - 1)
    ss_error = ss_total - sum(ss)
    if abs(ss_error) <= SS_ROUNDOFF_RTOL * ss_total:
        ss_error = 0.0
    total_dof = n_runs - 1
    error_dof = total_dof - sum(dof)
    if error_dof < 0:
        raise ValueError(f"factors use {sum(dof)} degrees of freedom; the array has only {total_dof}")
    ms = [v / d for v, d in zip(ss, dof)]
    ms_error = ss_error / error_dof if error_dof > 0 else float("nan")
    if error_dof > 0 and ms_error > 0.0:
        f_ratio = tuple(v / ms_error for v in ms)
    else:
        f_ratio = tuple(float("nan") for _ in ms)
    if ss_total > 0.0:
        contribution = tuple(100.0 * v / ss_total for v in ss)
        error_contribution = 100.0 * ss_error / ss_total
    else:
        warnings.warn(
            "all S/N ratios are equal: percentage contributions are undefined (NaN)",
            RuntimeWarning,
            stacklevel=2,
        )
        contribution = tuple(float("nan") for _ in ss)
        error_contribution = float("nan")
    return AnovaTable(
        factors=table.factors,
        dof=tuple(dof),
        sum_of_squares=tuple(ss),
        mean_square=tuple(ms),
        f_ratio=f_ratio,
        contribution_percent=contribution,
        error_dof=error_dof,
        error_sum_of_squares=ss_error,
        error_mean_square=ms_error,
        error_contribution_percent=error_contribution,
        total_dof=total_dof,
        total_sum_of_squares=ss_total,
    )


def best_levels(table: ResponseTable) -> tuple[int, ...]:
    """The 0-based level with the largest mean S/N, for every factor.

    Parameters
    ----------
    table : ResponseTable

    Returns
    -------
    tuple of int
        Ties go to the lowest level index.

    References
    ----------
    Phadke (1989), Ch. 3 (optimum settings from the main effects).
    """
    return tuple(int(np.argmax(m)) for m in table.level_means)


def predict_sn(
    table: ResponseTable, levels: Sequence[int] | Mapping[str, int] | None = None
) -> float:
    """Additive-model S/N at chosen factor levels.

    Parameters
    ----------
    table : ResponseTable
    levels : sequence of int or mapping of factor name to int, optional
        0-based level of every factor; default :func:`best_levels`.

    Returns
    -------
    float
        Predicted S/N in dB.

    Raises
    ------
    ValueError
        Wrong number of levels, unknown factor names, or out-of-range levels.

    Maths
    -----
    .. math:: \\hat\\eta = \\bar\\eta + \\sum_j \\big(m_{j,k_j} - \\bar\\eta\\big)

    References
    ----------
    Phadke (1989), Ch. 3 (prediction under the additive model);
    Ross (1996) (estimate of the optimum performance).
    """
    if levels is None:
        chosen: Sequence[int] = best_levels(table)
    elif isinstance(levels, Mapping):
        unknown = set(levels) - set(table.factors)
        missing = set(table.factors) - set(levels)
        if unknown or missing:
            raise ValueError(
                f"levels must name every factor of {table.factors}; "
                f"unknown {sorted(unknown)}, missing {sorted(missing)}"
            )
        chosen = [levels[f] for f in table.factors]
    else:
        chosen = list(levels)
    if len(chosen) != len(table.factors):
        raise ValueError(f"{len(chosen)} levels for {len(table.factors)} factors {table.factors}")
    eta = table.overall_mean
    for name, k, m in zip(table.factors, chosen, table.level_means):
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < len(m):
            raise ValueError(f"factor {name}: level must be an integer in 0..{len(m) - 1}, got {k!r}")
        eta += m[int(k)] - table.overall_mean
    return float(eta)


def analyze(
    oa: OrthogonalArray | npt.ArrayLike,
    sn: npt.ArrayLike,
    factor_names: Sequence[str] | None = None,
    columns: Sequence[int] | None = None,
) -> TaguchiAnalysis:
    """Response table, ANOVA, best levels and predicted S/N in one call.

    Parameters
    ----------
    oa, sn, factor_names, columns
        As in :func:`response_table`.

    Returns
    -------
    TaguchiAnalysis

    Warns
    -----
    RuntimeWarning
        As :func:`anova`, when all S/N ratios are equal.
    """
    table = response_table(oa, sn, factor_names, columns)
    aov = anova(oa, sn, factor_names, columns)
    best = best_levels(table)
    return TaguchiAnalysis(
        response_table=table, anova=aov, best_levels=best, predicted_sn=predict_sn(table, best)
    )
