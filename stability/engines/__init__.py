"""The Floquet front door: one call, a registry of engines, one rule that picks one.

``floquet(system, period=None, *, method="auto", rtol=DEFAULT_RTOL, **options) -> FloquetSolution``
in the style of ``scipy.integrate.solve_ivp``:

* ``system``: a callable ``t -> P(t)`` (with ``period``), or an object carrying ``.period`` with
  ``evaluate(times)`` or ``__call__`` (:class:`~stability.periodic.SecondOrderPeriodicSystem`, the
  reduced model, :class:`linearize.system.LinearizedPeriodicSystem`, whose sampled ``M, C, K`` also
  admit Hill's method);
* ``method``: a key of :data:`ENGINES` -- ``"magnus"``, ``"modal"``, ``"hill"``, ``"implicit"``,
  ``"paper"`` -- or ``"auto"``: the rule of :mod:`stability.engines.rule` from the system's size,
  stiffness, smoothness and the requested accuracy (never from a model's name);
* ``rtol``: the requested relative accuracy (default :data:`stability.floquet.DEFAULT_RTOL`, 2e-9, the
  default of the engines themselves), passed to the engine, which certifies its number to it or raises;
* ``options``: the engine's own (each engine lists what it accepts; anything else is a ``TypeError``).

Every engine returns :class:`FloquetSolution` (the multipliers, the spectral radius, the engine's
estimate, whether the spectrum is complete, and the engine's own result in ``detail``).

========== ================================================ ==============================================
engine     used for                                         how its number is certified
========== ================================================ ==============================================
magnus     small, smooth, non-stiff systems (``order`` 6,   steps refined until the Richardson estimate of
           4, or 2 for stiff fast ``P``)                    the moduli meets ``rtol``; Liouville residual
modal      stiff linearised FE models whose frozen modes    Richardson extrapolation in the frozen-modal
           keep their frequencies over the period           frame; optional non-nested check solve
hill       stiff models whose frozen frequencies change     H vs H/2 harmonics; backward error per pair
           along the period (sampled trigonometric M, C, K)
implicit   the few largest multipliers of large systems     ARPACK residual per Ritz pair; N vs N/2
paper      the independent reference                        the paper's procedure with ``solve_ivp``
========== ================================================ ==============================================
"""
from __future__ import annotations

from typing import Any, Optional

from stability.engines import hill as _hill  # noqa: F401  (registers the engine)
from stability.engines import implicit as _implicit  # noqa: F401
from stability.engines import magnus as _magnus  # noqa: F401
from stability.engines import modal as _modal  # noqa: F401
from stability.engines.base import ENGINES, Engine, FloquetSolution, engine, register
from stability.engines.rule import SystemProperties, choose_method, system_properties
from stability.floquet import DEFAULT_RTOL

__all__ = ["floquet", "FloquetSolution", "Engine", "ENGINES", "register", "engine", "choose_method",
           "system_properties", "SystemProperties"]


def floquet(system: Any, period: Optional[float] = None, *, method: str = "auto", rtol: float = DEFAULT_RTOL,
            **options: Any) -> FloquetSolution:
    """Floquet multipliers of ``x' = P(t) x`` by the engine ``method`` (see the module docstring).

    Parameters
    ----------
    system : callable or periodic-system object
    period : float, optional
        ``T``; required when ``system`` carries no ``.period``.
    method : str
        ``"auto"`` (the rule :func:`choose_method` on :func:`system_properties`) or a key of
        :data:`ENGINES`.
    rtol : float
        Requested relative accuracy (default :data:`stability.floquet.DEFAULT_RTOL`, as for the engines
        called directly).
    **options
        The engine's options (:attr:`Engine.options`).

    Returns
    -------
    FloquetSolution

    Raises
    ------
    ValueError
        Unknown method, bad period or ``rtol``.
    TypeError
        An option the engine does not accept.
    ArithmeticError
        The engine's numerical failure (``FloquetError``, ``ModalBasisError``, ``HillError``).
    """
    if method == "auto":
        method = choose_method(system_properties(system, period), rtol=rtol)
    eng = engine(method)
    eng.check_options(options)
    return eng.solution(eng.run(system, period, rtol, **dict(options)))
