"""Floquet evaluations of a periodic system inside a loop over feedback gains.

A PD controller changes a few entries of ``K`` and ``C`` only, so the
first-order matrix is affine in the gains with rank-one terms:

    P(t; g) = P_0(t) + sum_i g_i b_i(t) c_i^T                        (1)

(for a gain ``k`` on ``K[j, j]`` of ``M y'' + C y' + K y = 0``:
``b(t) = [0; -M(t)^-1 e_j]``, ``c = [e_j; 0]``; on ``C[j, j]``: the same
``b``, ``c = [0; e_j]``).  :class:`GainParametrisedSystem` holds Eq. (1);
:class:`FloquetWorkspace` samples ``P_0`` and the ``b_i`` once at the Gauss
points of a fixed step count (and balances once), so that each evaluation
costs only the rank-one updates, the exponentials, the product and the
eigenvalues -- no interpolation of the linearisation, no mass-matrix solves,
no validation or balancing repeated per gain pair.

The workspace evaluates exactly what ``stability.floquet(family.with_gains(g),
method=..., n_steps=...)`` evaluates (same scheme, same nodes, same balancing
up to the diagonal scaling, which leaves the multipliers unchanged).

The tuning seams live here too, on the ground floor every stage may import: :class:`Gains` (one
``(kp, kd)`` pair per drive, and the interleaved vector ``(kp1, kd1, kp2, kd2, ...)`` a Taguchi
experiment varies) and the protocols :class:`Plant` / :class:`MeasuredPlant` a tuning loop,
a chart or a validation calls on a model.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional, Protocol, Sequence, Union, runtime_checkable

import numpy as np

from stability.expm import expm_stack
from stability.floquet import (
    FloquetError,
    FloquetResult,
    _balancing_scale,
    _spectrum,
    _verdict,
)
from stability.magnus import MAGNUS2, MAGNUS4, MAGNUS6, magnus_exponents, ordered_product
from stability.periodic import PeriodicMatrixFunction, check_period

__all__ = ["Gains", "Plant", "MeasuredPlant", "GainParametrisedSystem", "FloquetWorkspace", "pd_gain_family"]

#: What a plant's ``with_gains``/``spectral_measure`` take for ``kp`` (and ``kd``): a float for a
#: one-drive plant, one value per drive otherwise (:meth:`Gains.arguments`).
GainArgument = Union[float, Sequence[float]]


@runtime_checkable
class Plant(Protocol):
    """A model that accepts PD gains: what tuning, charts and validation call on it.

    ``with_gains(kp, kd)`` returns the periodic system at those gains, a system
    :func:`stability.floquet` (or the front door :func:`stability.engines.floquet`) accepts;
    ``kp``/``kd`` as :meth:`Gains.arguments` gives them (a float per gain for one drive, one
    value per drive otherwise).  Implemented by :class:`mbs_models.reduced.ReducedModel`,
    :class:`linearize.system.LinearizedPeriodicSystem` and the tuning plants of
    :mod:`linearize.analysis` and :mod:`linearize.hill_plant`.  (:class:`GainParametrisedSystem` is
    not one: its ``with_gains`` takes the gain vector of Eq. (1) whole.)
    """

    def with_gains(self, kp: GainArgument, kd: GainArgument) -> Any:
        ...


@runtime_checkable
class MeasuredPlant(Protocol):
    """A plant that defines its own tuning response ``spectral_measure(kp, kd) -> |rho|``.

    E.g. the dominant *labelled* multiplier of a model file's linearisation
    (:class:`linearize.analysis.ModelPlant`, :class:`linearize.hill_plant.HillModelPlant`): the
    undamped structural modes of a finite-element mesh keep ``|rho| = 1`` whatever the gains, so
    the spectral radius of :meth:`Plant.with_gains` is not the tuned quantity.  A tuning objective
    (:class:`taguchi.tuning.GainObjective`) uses this response when the plant has it, else the
    spectral radius of ``with_gains``.
    """

    def spectral_measure(self, kp: GainArgument, kd: GainArgument) -> float:
        ...


@dataclass(frozen=True)
class Gains:
    """PD gains: one ``(kp, kd)`` pair per drive.

    A Taguchi experiment varies the *interleaved* vector ``(kp1, kd1, kp2, kd2, ...)``
    (:meth:`from_interleaved`, :meth:`interleaved`); a plant takes ``kp`` and ``kd`` apart
    (:meth:`arguments`).

    Attributes
    ----------
    kp, kd : tuple of float
        One value per drive (the same number of each, at least one).
    """

    kp: tuple
    kd: tuple

    def __post_init__(self) -> None:
        kp, kd = (tuple(float(v) for v in np.atleast_1d(np.asarray(x, dtype=float)).ravel())
                  for x in (self.kp, self.kd))
        if not kp or len(kp) != len(kd):
            raise ValueError(f"gains: one (kp, kd) pair per drive, got {len(kp)} kp and {len(kd)} kd values")
        object.__setattr__(self, "kp", kp)
        object.__setattr__(self, "kd", kd)

    @classmethod
    def from_interleaved(cls, values: Sequence[float]) -> "Gains":
        """From ``(kp1, kd1, kp2, kd2, ...)``; ``ValueError`` for an odd or zero count."""
        g = [float(v) for v in np.asarray(values, dtype=float).ravel()]
        if not g or len(g) % 2:
            raise ValueError(f"gains must be (kp, kd) pairs per drive, got {len(g)} values")
        return cls(tuple(g[0::2]), tuple(g[1::2]))

    @classmethod
    def from_arrays(cls, kp: GainArgument, kd: GainArgument) -> "Gains":
        """From one ``kp`` and one ``kd`` per drive (a float: one drive)."""
        return cls(kp, kd)

    @property
    def drives(self) -> int:
        """Number of drives."""
        return len(self.kp)

    def interleaved(self) -> tuple:
        """``(kp1, kd1, kp2, kd2, ...)``."""
        return tuple(v for pair in zip(self.kp, self.kd) for v in pair)

    def arguments(self) -> tuple:
        """``(kp, kd)`` as a plant's ``with_gains`` / ``spectral_measure`` take them: floats for one drive
        (what a one-drive plant such as the reduced model accepts), tuples of one value per drive otherwise."""
        if self.drives == 1:
            return self.kp[0], self.kd[0]
        return self.kp, self.kd

_SCHEMES = {"magnus2": MAGNUS2, "magnus4": MAGNUS4, "magnus6": MAGNUS6}


@dataclass(frozen=True)
class GainParametrisedSystem:
    """``P(t; g) = P_0(t) + sum_i g_i b_i(t) c_i^T`` (Eq. 1 of the module notes).

    Parameters
    ----------
    base : periodic matrix
        ``P_0`` (callable ``t -> (n, n)``, optionally ``evaluate(times)`` and ``.period``).
    inputs : callable
        ``times (m,) -> B (m, n, k)``: the columns ``b_i(t)``.
    outputs : ndarray, shape (k, n), or callable
        The rows ``c_i``; or ``times (m,) -> C (m, k, n)`` when they vary in time
        (e.g. a drive whose coordinate is a time-dependent combination of the
        state, ``P(t; g) = P_0(t) + sum_i g_i b_i(t) c_i(t)^T``).
    names : tuple of str
        Gain names (for messages).
    period : float, optional
        Taken from ``base.period`` when omitted.
    """

    base: Any
    inputs: Callable[[np.ndarray], np.ndarray]
    outputs: np.ndarray
    names: tuple = ()
    period: Optional[float] = None

    def __post_init__(self) -> None:
        T = self.period if self.period is not None else getattr(self.base, "period", None)
        if T is None:
            raise ValueError("period is required: the base system carries no .period")
        object.__setattr__(self, "period", check_period(T))
        if callable(self.outputs):
            k = np.asarray(self.outputs(np.zeros(1)), dtype=float)
            if k.ndim != 3 or k.shape[0] != 1 or not np.all(np.isfinite(k)):
                raise ValueError(f"outputs(times) must return finite (m, k, n) arrays, got shape {k.shape}")
            object.__setattr__(self, "_n_gains", int(k.shape[1]))
            if not self.names:
                object.__setattr__(self, "names", tuple(f"g{i}" for i in range(k.shape[1])))
            return
        C = np.atleast_2d(np.asarray(self.outputs, dtype=float))
        if not np.all(np.isfinite(C)):
            raise ValueError("outputs contain NaN or inf")
        object.__setattr__(self, "outputs", C)
        if not self.names:
            object.__setattr__(self, "names", tuple(f"g{i}" for i in range(C.shape[0])))

    @property
    def n_gains(self) -> int:
        if callable(self.outputs):
            return self._n_gains  # type: ignore[attr-defined]
        return int(self.outputs.shape[0])

    def output_rows(self, times: np.ndarray) -> np.ndarray:
        """``c_i(t)`` stacked over ``times``, shape ``(m, k, n)``."""
        t = np.atleast_1d(np.asarray(times, dtype=float))
        if callable(self.outputs):
            return np.asarray(self.outputs(t), dtype=float)
        return np.broadcast_to(self.outputs, (t.size,) + self.outputs.shape)

    def _gains(self, gains: Sequence[float]) -> np.ndarray:
        g = np.asarray(gains, dtype=float).ravel()
        if g.size != self.n_gains or not np.all(np.isfinite(g)):
            raise ValueError(f"expected {self.n_gains} finite gains ({', '.join(self.names)}), got {gains!r}")
        return g

    def evaluate(self, times: np.ndarray, gains: Sequence[float]) -> np.ndarray:
        """``P(t; g)`` stacked over ``times``, shape ``(m, n, n)``."""
        g = self._gains(gains)
        t = np.atleast_1d(np.asarray(times, dtype=float))
        wrapped = PeriodicMatrixFunction(self.base, self.period)
        return wrapped.evaluate(t) + np.einsum("mnk,k,mkj->mnj", self.inputs(t), g, self.output_rows(t))

    def with_gains(self, gains: Sequence[float]) -> "_WithGains":
        """A periodic matrix object (``period``, ``evaluate``, ``__call__``) for fixed gains."""
        return _WithGains(self, tuple(float(v) for v in self._gains(gains)))

    def workspace(self, n_steps: int, method: str = "magnus2", balance: bool = True) -> "FloquetWorkspace":
        """A :class:`FloquetWorkspace` for this family."""
        return FloquetWorkspace(self, n_steps, method=method, balance=balance)


@dataclass(frozen=True)
class _WithGains:
    family: GainParametrisedSystem
    gains: tuple

    @property
    def period(self) -> float:
        return float(self.family.period)  # type: ignore[arg-type]

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        return self.family.evaluate(times, self.gains)

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([float(t)]))[0]


def pd_gain_family(system: Any, index: int = 0) -> GainParametrisedSystem:
    """Eq. (1) for PD gains ``(kp, kd)`` on coordinate ``index`` of ``M y'' + C y' + K y = 0``.

    Parameters
    ----------
    system : object
        With ``.period``, ``evaluate(times)`` (the first-order ``P`` at zero
        gains) and ``matrices(times) -> (M, C, K)`` (e.g.
        :class:`~stability.periodic.SecondOrderPeriodicSystem` or a
        linearisation), at zero gains.
    index : int
        The controlled coordinate ``j``.

    Notes
    -----
    ``K -> K + kp e_j e_j^T`` and ``C -> C + kd e_j e_j^T`` change ``P = [[0, I],
    [-M^-1 K, -M^-1 C]]`` by ``kp b c_p^T + kd b c_d^T`` with ``b = [0; -M^-1 e_j]``,
    ``c_p = [e_j; 0]``, ``c_d = [0; e_j]``.
    """
    M0 = system.matrices(np.array([0.0]))[0]
    f = M0.shape[-1]
    if isinstance(index, bool) or int(index) != index or not 0 <= index < f:
        raise ValueError(f"index must be an integer in [0, {f - 1}], got {index!r}")
    outputs = np.zeros((2, 2 * f))
    outputs[0, index] = 1.0
    outputs[1, f + index] = 1.0
    return GainParametrisedSystem(system, _PDInputs(system, int(index)), outputs, names=("kp", "kd"),
                                  period=system.period)


@dataclass(frozen=True)
class _PDInputs:
    """``times -> B (m, 2f, 2)`` with both columns ``[0; -M(t)^-1 e_j]`` (picklable)."""

    system: Any
    index: int

    def __call__(self, times: np.ndarray) -> np.ndarray:
        M = self.system.matrices(times)[0]
        m, f = M.shape[0], M.shape[-1]
        e = np.zeros((m, f, 1))
        e[:, self.index, 0] = 1.0
        col = -np.linalg.solve(M, e)[..., 0]
        b = np.zeros((m, 2 * f, 2))
        b[:, f:, 0] = col
        b[:, f:, 1] = col
        return b


class FloquetWorkspace:
    """Cached samples of a :class:`GainParametrisedSystem` for repeated Floquet evaluations.

    Parameters
    ----------
    family : GainParametrisedSystem
    n_steps : int
        Sub-intervals (fixed: the loop compares gains at one discretisation).
    method : {"magnus2", "magnus4", "magnus6"}
    balance : bool
        Balance once, from ``P_0`` (a constant diagonal similarity: the
        multipliers of every ``P(t; g)`` are unchanged by it).
    """

    def __init__(self, family: GainParametrisedSystem, n_steps: int, method: str = "magnus2",
                 balance: bool = True) -> None:
        if method not in _SCHEMES:
            raise ValueError(f"method must be one of {', '.join(sorted(_SCHEMES))}, got {method!r}")
        if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 1:
            raise ValueError(f"n_steps must be a positive integer, got {n_steps!r}")
        self.family = family
        self.scheme = _SCHEMES[method]
        self.n_steps = int(n_steps)
        T = float(family.period)  # type: ignore[arg-type]
        self.period = T
        wrapped = PeriodicMatrixFunction(family.base, T)
        n = wrapped.n
        nodes = np.asarray(self.scheme.nodes)
        self.h = T / self.n_steps
        times = ((np.arange(self.n_steps)[:, None] + nodes[None, :]) * self.h).ravel()
        P0 = wrapped.evaluate(times)
        B = np.asarray(family.inputs(times), dtype=float)
        if B.shape != (times.size, n, family.n_gains):
            raise ValueError(f"inputs(times) must have shape {(times.size, n, family.n_gains)}, got {B.shape}")
        scale = _balancing_scale(P0[:: max(1, times.size // 16)]) if balance else None
        Cout = family.output_rows(times)
        if scale is not None:
            P0 = P0 * (scale[None, :] / scale[:, None])[None]
            B = B / scale[None, :, None]
            Cout = Cout * scale[None, None, :]
        self.scale = scale
        self._P0 = P0.reshape(self.n_steps, len(nodes), n, n)
        self._B = B.reshape(self.n_steps, len(nodes), n, family.n_gains)
        self._C = np.ascontiguousarray(Cout).reshape(self.n_steps, len(nodes), family.n_gains, n)
        self.n = n

    def monodromy(self, gains: Sequence[float]) -> tuple[np.ndarray, float]:
        """Balanced ``Phi(T)`` and ``sum tr Omega_k`` for ``gains``."""
        g = self.family._gains(gains)
        Pg = self._P0 + np.einsum("sqnk,k,sqkj->sqnj", self._B, g, self._C)
        with np.errstate(over="ignore", invalid="ignore"):
            Om = magnus_exponents(self.scheme, Pg, self.h)
            Phi = ordered_product(expm_stack(Om))
        if not np.all(np.isfinite(Phi)):
            raise FloquetError(f"{self.scheme.name}: the monodromy overflowed with {self.n_steps} sub-intervals "
                               f"at gains {dict(zip(self.family.names, g))}")
        return Phi, float(np.trace(np.sum(Om, axis=0)))

    def floquet(self, gains: Sequence[float], stability_tol: float = 1e-8) -> FloquetResult:
        """:class:`~stability.floquet.FloquetResult` for ``gains`` (no error estimate: fixed steps)."""
        t0 = time.perf_counter()
        Phi, log_det = self.monodromy(gains)
        spec = _spectrum(Phi)
        rho = float(math.exp(spec.log_moduli[0]))
        noise = float(self.n * np.finfo(float).eps * np.linalg.norm(Phi, 2))
        with np.errstate(divide="ignore", under="ignore"):
            digits = np.clip(np.log10(np.exp(spec.log_moduli) / noise), 0.0, 16.0)
        monodromy = Phi if self.scale is None else Phi * self.scale[:, None] / self.scale[None, :]
        return FloquetResult(
            multipliers=spec.values,
            log_moduli=spec.log_moduli,
            monodromy=monodromy,
            spectral_radius=rho,
            verdict=_verdict(rho, stability_tol),
            stability_tolerance=stability_tol,
            liouville_residual=math.nan,
            liouville_source="unavailable",
            multiplier_liouville_residual=math.nan,
            trace_integral=math.nan,
            error_estimate=math.nan,
            noise_floor=noise,
            reliable_digits=digits,
            method=self.scheme.name,
            n_steps=self.n_steps,
            n_evaluations=0,
            period=self.period,
            elapsed=time.perf_counter() - t0,
            accuracy="moduli",
        )
