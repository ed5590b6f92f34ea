"""The engine base class, the registry and the one result type of the Floquet front door.

Rules for an implementer of an engine (a subclass of :class:`Engine`):

1. Set :attr:`Engine.name` (the registry key, the ``method=`` of :func:`stability.engines.floquet`)
   and :attr:`Engine.options` (every keyword option the engine accepts besides ``rtol``); decorate
   the class with :func:`register`.
2. Implement :meth:`Engine.run`: take the *system* (see :func:`stability.engines.floquet`), its
   ``period`` (``None`` when the system carries ``.period``), ``rtol`` and the options; return the
   engine's own result.  Never read a model's name: what an engine may use is the system's
   matrices and period.
3. Implement :meth:`Engine.solution` to map that result to :class:`FloquetSolution`: the
   multipliers it computed (sorted by modulus, descending), whether they are the whole spectrum
   (:attr:`Engine.complete`), and the engine's own relative error estimate of them.
4. Raise the engine's numerical error (an ``ArithmeticError`` subclass: ``FloquetError``,
   ``ModalBasisError``, ``HillError``) when it cannot certify its number; never return NaN silently.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Optional

import numpy as np

__all__ = ["Engine", "FloquetSolution", "ENGINES", "register", "engine"]


@dataclass(frozen=True)
class FloquetSolution:
    """What every engine of :func:`stability.engines.floquet` returns.

    Attributes
    ----------
    multipliers : ndarray, complex
        The multipliers the engine computed, sorted by modulus, descending: the whole spectrum when
        ``complete``, else the subset the engine targets (Hill: near its targets; implicit: the
        ``k`` largest).
    spectral_radius : float
        Largest modulus of ``multipliers`` (the system's spectral radius when ``complete`` or when the
        engine computes the largest moduli, as the implicit engine does).
    error_estimate : float
        The engine's own estimate of the largest relative error of ``multipliers`` (NaN when it has
        none).
    complete : bool
        Whether ``multipliers`` is the whole spectrum.
    method : str
        The engine that ran (a key of :data:`ENGINES`).
    period : float
    detail : object
        The engine's own result (:class:`~stability.floquet.FloquetResult`,
        :class:`~stability.modal.ModalFloquetResult`, :class:`~stability.hill.HillResult`,
        :class:`~stability.implicit.ImplicitFloquetResult`) with everything else it reports.
    """

    multipliers: np.ndarray
    spectral_radius: float
    error_estimate: float
    complete: bool
    method: str
    period: float
    detail: Any

    @property
    def moduli(self) -> np.ndarray:
        """``|rho_i|``, descending."""
        return np.abs(self.multipliers)


#: The registry: engine name -> engine class.
ENGINES: dict[str, type["Engine"]] = {}


def register(cls: type["Engine"]) -> type["Engine"]:
    """Class decorator: add ``cls`` to :data:`ENGINES` under ``cls.name``."""
    if not getattr(cls, "name", None):
        raise TypeError(f"{cls.__name__}: an engine needs a name")
    ENGINES[cls.name] = cls
    return cls


def engine(name: str) -> "Engine":
    """An instance of the engine called ``name``; ``ValueError`` naming the known ones otherwise."""
    try:
        return ENGINES[name]()
    except KeyError:
        raise ValueError(f"unknown Floquet method {name!r}; known: {', '.join(sorted(ENGINES))}") from None


class Engine:
    """A Floquet engine behind :func:`stability.engines.floquet` (see the module docstring's rules)."""

    #: Registry key.
    name: ClassVar[str] = ""
    #: Keyword options accepted besides ``rtol`` (anything else is rejected).
    options: ClassVar[frozenset[str]] = frozenset()
    #: Whether the engine computes the whole spectrum.
    complete: ClassVar[bool] = True

    def check_options(self, options: dict) -> None:
        """``TypeError`` naming every option this engine does not accept."""
        unknown = sorted(set(options) - set(self.options))
        if unknown:
            raise TypeError(f"method {self.name!r} does not accept {', '.join(unknown)}; "
                            f"its options: {', '.join(sorted(self.options)) or 'none'}")

    def run(self, system: Any, period: Optional[float], rtol: float, **options: Any) -> Any:
        """The engine's own result for ``system``."""
        raise NotImplementedError

    def solution(self, result: Any) -> FloquetSolution:
        """:class:`FloquetSolution` of a result of :meth:`run` (default: a ``FloquetResult``)."""
        mult = np.asarray(result.multipliers)
        return FloquetSolution(multipliers=mult, spectral_radius=float(result.spectral_radius),
                               error_estimate=float(result.error_estimate), complete=self.complete,
                               method=self.name, period=float(result.period), detail=result)


def _sorted(multipliers: np.ndarray) -> np.ndarray:
    m = np.asarray(multipliers, dtype=complex)
    return m[np.argsort(-np.abs(m), kind="stable")]

