"""Taguchi signal-to-noise (S/N) ratios, in decibels.

Every ratio is ``-10 log10`` of a mean-squared deviation (MSD) or, for
nominal-the-best type I, ``10 log10`` of a squared mean over a variance.
Larger S/N is always better.

Which ratio this project uses
-----------------------------
Each run of the PD-gain array gives one *deterministic* response,
``y = max_i |rho_i(kp, kd)|`` (the spectral radius of the monodromy matrix),
and the goal is a known target ``rho_d`` (paper, Eq. 34).  The textbook
nominal-the-best ratio ``10 log10(ybar^2 / s^2)`` needs a spread ``s`` between
replicates and is undefined for one deterministic run, so the tuner uses
:func:`sn_target`: quadratic loss ``(y - rho_d)^2`` and
``S/N = -10 log10(loss)``.

A run that hits the target exactly has loss 0 and S/N = +inf, which would
break every mean in the analysis; the loss is therefore clipped below at
:data:`LOSS_FLOOR` (``1e-30``), i.e. S/N at most :data:`SN_CEILING_DB`
(300 dB), far above anything a floating-point response can resolve
(``|y - rho_d| = 1e-15`` already gives 300 dB).  The same floor is applied to
the smaller-the-better MSD.

References
----------
.. [1] G. Taguchi, *Introduction to Quality Engineering*, Asian Productivity
   Organization, 1986.
.. [2] M. S. Phadke, *Quality Engineering Using Robust Design*,
   Prentice Hall, 1989, Ch. 5 (S/N ratios; quality loss function Ch. 2).
.. [3] P. J. Ross, *Taguchi Techniques for Quality Engineering*, 2nd ed.,
   McGraw-Hill, 1996 (chapter on S/N ratios).
.. [4] D. C. Montgomery, *Design and Analysis of Experiments*, 8th ed.,
   Wiley, 2013, Ch. 12 (discussion of Taguchi's S/N ratios).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

__all__ = [
    "LOSS_FLOOR",
    "SN_CEILING_DB",
    "SN_RATIOS",
    "larger_the_better",
    "nominal_the_best",
    "nominal_the_best_type2",
    "quadratic_loss",
    "smaller_the_better",
    "sn_ratio",
    "sn_ratios",
    "sn_target",
]

logger = logging.getLogger(__name__)

#: Smallest mean loss (MSD) fed to ``log10``: a response exactly on target
#: would otherwise give S/N = +inf and break level means in the analysis.
#: 1e-30 is far below (1e-15)^2, the squared resolution of a double near 1.
LOSS_FLOOR: float = 1e-30

#: Largest S/N any MSD-based ratio can return, ``-10 log10(LOSS_FLOOR)`` = 300 dB.
SN_CEILING_DB: float = -10.0 * np.log10(LOSS_FLOOR)


def _observations(y: npt.ArrayLike, what: str) -> np.ndarray:
    """Return the replicates of one run as a finite 1-D float array, or raise."""
    a = np.asarray(y, dtype=float)
    if a.ndim > 1:
        raise ValueError(f"{what}: expected the replicates of one run (scalar or 1-D), got shape {a.shape}")
    a = np.atleast_1d(a)
    if a.size == 0:
        raise ValueError(f"{what}: no observations (empty data)")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: observations must be finite, got {a.tolist()}")
    return a


def _db_of_msd(msd: float) -> float:
    return float(-10.0 * np.log10(max(msd, LOSS_FLOOR)))


def smaller_the_better(y: npt.ArrayLike) -> float:
    """Smaller-the-better S/N ratio.

    Parameters
    ----------
    y : float or array_like, shape (n,)
        The ``n`` replicates of one run.

    Returns
    -------
    float
        S/N in dB; at most :data:`SN_CEILING_DB` (all-zero data).

    Raises
    ------
    ValueError
        Empty data or non-finite values.

    Maths
    -----
    .. math:: \\eta = -10 \\log_{10}\\Big(\\frac{1}{n}\\sum_{i=1}^n y_i^2\\Big)

    References
    ----------
    Phadke (1989), Ch. 5; Ross (1996), chapter on S/N ratios.
    """
    a = _observations(y, "smaller_the_better")
    return _db_of_msd(float(np.mean(a * a)))


def larger_the_better(y: npt.ArrayLike) -> float:
    """Larger-the-better S/N ratio.

    Parameters
    ----------
    y : float or array_like, shape (n,)
        The ``n`` replicates of one run; must be non-zero.

    Returns
    -------
    float
        S/N in dB.

    Raises
    ------
    ValueError
        Empty data, non-finite values, or a zero observation (its ``1/y^2`` is
        infinite: S/N = -inf).

    Maths
    -----
    .. math:: \\eta = -10 \\log_{10}\\Big(\\frac{1}{n}\\sum_{i=1}^n \\frac{1}{y_i^2}\\Big)

    References
    ----------
    Phadke (1989), Ch. 5; Ross (1996), chapter on S/N ratios.
    """
    a = _observations(y, "larger_the_better")
    if np.any(a == 0.0):
        raise ValueError("larger_the_better: a zero observation makes 1/y^2 infinite (S/N = -inf)")
    return float(-10.0 * np.log10(np.mean(1.0 / (a * a))))


def nominal_the_best(y: npt.ArrayLike) -> float:
    """Nominal-the-best S/N ratio, type I (mean and spread adjustable separately).

    Not usable for one deterministic run: with ``n < 2`` replicates, or with
    identical replicates (``s = 0``), the ratio is undefined and a
    ``ValueError`` is raised.  For a single deterministic response with a
    known target (this project's ``max |rho|`` against ``rho_d``) use
    :func:`sn_target`.

    Parameters
    ----------
    y : array_like, shape (n,), n >= 2
        Replicates of one run.

    Returns
    -------
    float
        S/N in dB.

    Raises
    ------
    ValueError
        Fewer than two observations, zero sample variance, a zero mean, or
        non-finite values.

    Maths
    -----
    .. math::
        \\eta = 10 \\log_{10}\\frac{\\bar y^2}{s^2},\\quad
        \\bar y = \\frac1n\\sum y_i,\\quad
        s^2 = \\frac{1}{n-1}\\sum (y_i - \\bar y)^2

    References
    ----------
    Phadke (1989), Ch. 5; Ross (1996), chapter on S/N ratios;
    Montgomery (2013), Ch. 12.
    """
    a = _observations(y, "nominal_the_best")
    if a.size < 2:
        raise ValueError(
            "nominal_the_best: needs at least 2 replicates (s^2 is undefined for n = 1); "
            "for one deterministic response with a known target use sn_target"
        )
    s2 = float(np.var(a, ddof=1))
    if s2 == 0.0:
        raise ValueError(
            "nominal_the_best: replicates are identical (s = 0, S/N = +inf); "
            "for a deterministic response with a known target use sn_target"
        )
    ybar = float(np.mean(a))
    if ybar == 0.0:
        raise ValueError("nominal_the_best: mean is zero (S/N = -inf); use nominal_the_best_type2")
    return float(10.0 * np.log10(ybar * ybar / s2))


def nominal_the_best_type2(y: npt.ArrayLike) -> float:
    """Nominal-the-best S/N ratio, type II (variance only; signed responses).

    Parameters
    ----------
    y : array_like, shape (n,), n >= 2
        Replicates of one run.

    Returns
    -------
    float
        S/N in dB.

    Raises
    ------
    ValueError
        Fewer than two observations, zero variance, or non-finite values;
        use :func:`sn_target` for one deterministic run.

    Maths
    -----
    .. math:: \\eta = -10 \\log_{10} s^2,\\quad s^2 = \\frac{1}{n-1}\\sum (y_i - \\bar y)^2

    References
    ----------
    Phadke (1989), Ch. 5 ("signed target" case); Ross (1996), chapter on S/N ratios.
    """
    a = _observations(y, "nominal_the_best_type2")
    if a.size < 2:
        raise ValueError("nominal_the_best_type2: needs at least 2 replicates; use sn_target")
    s2 = float(np.var(a, ddof=1))
    if s2 == 0.0:
        raise ValueError("nominal_the_best_type2: replicates are identical (s = 0); use sn_target")
    return float(-10.0 * np.log10(s2))


def quadratic_loss(y: npt.ArrayLike, target: float) -> float:
    """Mean quadratic loss about a target (Taguchi's loss with ``k = 1``).

    Parameters
    ----------
    y : float or array_like, shape (n,)
        Response(s) of one run; for this project ``max_i |rho_i|``.
    target : float
        Target value, e.g. ``rho_d``.

    Returns
    -------
    float
        ``mean((y - target)^2)`` (not floored).

    Maths
    -----
    .. math:: L = \\frac1n\\sum_{i=1}^n (y_i - m)^2

    References
    ----------
    Phadke (1989), Ch. 2; paper Eq. (34) with ``y = max|rho|``,
    ``m = rho_d``.
    """
    return _mean_loss(y, target, "quadratic_loss")


def _mean_loss(y: npt.ArrayLike, target: float, what: str) -> float:
    a = _observations(y, what)
    try:
        t = float(target)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: target must be a finite number, got {target!r}") from None
    if not np.isfinite(t):
        raise ValueError(f"{what}: target must be finite, got {target!r}")
    d = a - t
    return float(np.mean(d * d))


def sn_target(y: npt.ArrayLike, target: float) -> float:
    """Target S/N ratio: ``-10 log10`` of the mean quadratic loss about ``target``.

    The ratio this project uses: one deterministic response per run,
    ``y = max_i |rho_i(kp, kd)|``, with target ``rho_d`` (paper, Eq. 34).
    Unlike :func:`nominal_the_best` it is defined for a single run.

    Parameters
    ----------
    y : float or array_like, shape (n,)
        Response(s) of one run.
    target : float
        Target value.

    Returns
    -------
    float
        S/N in dB, at most :data:`SN_CEILING_DB`: the loss is clipped at
        :data:`LOSS_FLOOR` so that a run exactly on target gives a large
        finite number instead of +inf.

    Raises
    ------
    ValueError
        Empty data, non-finite values or target.

    Maths
    -----
    .. math::
        L = \\frac1n\\sum_{i=1}^n (y_i - m)^2,\\qquad
        \\eta = -10 \\log_{10} \\max(L, L_{\\min})

    For ``n = 1``: ``eta = -20 log10 |y - m|``.  This is the MSD form of
    nominal-the-best (Ross 1996, Ch. 10: ``MSD = mean((y_i - m)^2)``).

    References
    ----------
    Phadke (1989), Ch. 2 and Ch. 5; Ross (1996), chapter on S/N ratios;
    paper, Eq. (34).
    """
    return _db_of_msd(_mean_loss(y, target, "sn_target"))


#: Registry of S/N ratios by the names a user or CLI passes.  ``"target"``
#: needs the ``target=`` keyword.
SN_RATIOS: Mapping[str, Callable[..., float]] = MappingProxyType(
    {
        "smaller": smaller_the_better,
        "larger": larger_the_better,
        "nominal": nominal_the_best,
        "nominal2": nominal_the_best_type2,
        "target": sn_target,
    }
)


def sn_ratio(y: npt.ArrayLike, kind: str, target: float | None = None) -> float:
    """S/N ratio of one run by registry name (see :data:`SN_RATIOS`).

    Parameters
    ----------
    y : float or array_like, shape (n,)
        Replicates of one run.
    kind : {'smaller', 'larger', 'nominal', 'nominal2', 'target'}
    target : float, optional
        Required for ``kind='target'``; not allowed otherwise.
    """
    if kind not in SN_RATIOS:
        raise ValueError(f"unknown S/N ratio {kind!r}; available: {', '.join(SN_RATIOS)}")
    if kind == "target":
        if target is None:
            raise ValueError("S/N ratio 'target' needs a target value")
        return sn_target(y, target)
    if target is not None:
        raise ValueError(f"S/N ratio {kind!r} takes no target")
    return SN_RATIOS[kind](y)


def sn_ratios(responses: npt.ArrayLike, kind: str, target: float | None = None) -> np.ndarray:
    """S/N ratio of every run of an experiment.

    Parameters
    ----------
    responses : array_like, shape (runs,) or (runs, replicates)
        One row per run (a 1-D array means one observation per run).
    kind, target
        As in :func:`sn_ratio`.

    Returns
    -------
    numpy.ndarray, shape (runs,)
    """
    r = np.asarray(responses, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    if r.ndim != 2 or r.shape[0] == 0 or r.shape[1] == 0:
        raise ValueError(f"responses must be a non-empty (runs,) or (runs, replicates) array, got shape {r.shape}")
    return np.array([sn_ratio(row, kind, target) for row in r])
