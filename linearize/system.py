"""The linearised periodic system ``M(t) y'' + C(t) y' + K(t) y = 0`` from samples."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from typing import Optional, Sequence

import numpy as np

from linearize.fourier import trig_interpolate
from linearize.piecewise import PiecewiseGrid
from stability.periodic import first_order_matrix

__all__ = ["LinearizedPeriodicSystem"]

#: Nested periodic trapezoidal rule of :meth:`LinearizedPeriodicSystem.trace_integral`: it starts
#: with ``TRACE_MIN_POINTS // 2`` points and doubles (reusing every value) until two successive sums
#: agree to ``stability.floquet.TRACE_RTOL`` relative to ``int |tr P|`` (the rule of
#: ``stability.floquet._trace_integral``: the trapezoidal error of a smooth periodic integrand
#: falls exponentially, so the change from ``K`` to ``2 K`` points bounds the error of the ``K``
#: sum), at most :data:`TRACE_POINTS` points; unconverged there it warns (``RuntimeWarning``).
TRACE_POINTS = 4096
TRACE_MIN_POINTS = 64


@dataclass(frozen=True)
class LinearizedPeriodicSystem:
    """Periodic matrices ``M, C, K`` sampled over one period, interpolated in time.

    A periodic matrix for :func:`stability.floquet`: it has ``.period``,
    ``__call__(t) -> P(t)`` and ``evaluate(times) -> (m, 2n, 2n)``, with
    ``P = [[0, I], [-M^-1 K, -M^-1 C]]`` built by
    :func:`stability.periodic.first_order_matrix` (the package's one place).

    Attributes
    ----------
    period : float
        ``T``.
    times : ndarray, shape (N,)
        Sample times ``k T / N``.
    M, C, K : ndarray, shape (N, n, n)
        Mass, damping and stiffness matrices at ``times`` (left-hand side,
        ``K = dr/dp``, ``C = dr/dp'``; PD gains included).
    kp, kd : float
        PD gains added to ``K[0, 0]`` and ``C[0, 0]`` (paper Eq. 32) when the
        hub coordinate is free; 0 for the prescribed hub.
    coordinates : tuple of str
        Names of the independent coordinates ``y``.
    hub_free : bool
        Whether coordinate 0 is the hub angle (free hub) or the hub is
        prescribed (beam coordinates only).
    reference : str
        ``"periodic"`` (linearised about the true periodic orbit) or
        ``"rigid"`` (about the undeformed rigid motion).
    orbit_residual : float
        Relative residual of the reference motion (see
        :class:`~linearize.periodic_orbit.PeriodicOrbit`).
    elements : int
        ANCF elements of the model.
    fd_step : float
        Relative central-difference step used.
    wall_time : float
        Seconds spent linearising.
    B : ndarray, shape (N, n, d), optional
        Drive input map of a model file's linearisation: column ``j`` maps a
        torque of drive ``j`` into the equations (``M y'' + C y' + K y = B u``).
        ``None`` for the hand-derived single link (hub = coordinate 0).
    B_t : ndarray, shape (N, n, d), optional
        Rate map of the driven coordinates: ``delta(driven)' = B^T y' + B_t^T y``
        (``B^T y`` is the driven coordinate itself).  PD gains enter as
        ``K += B kp B^T + B kd B_t^T``, ``C += B kd B^T``.
    drive_names : tuple of str
        Names of the drives (columns of ``B``).
    basis, basis_t : ndarray, shape (N, n_ode2, n), optional
        ``delta q = N(t) y`` and ``N'(t)``: the map back to Exudyn's ODE2
        coordinates (a model file's linearisation); ``delta q' = N y' + N' y``.
    breakpoints : tuple of float
        Piece boundaries of a piecewise-sampled orbit (a drive with declared breakpoints,
        :mod:`linearize.piecewise`; ``0`` included): the samples are that grid's nodes and ``P`` is
        interpolated piece by piece.  :func:`stability.floquet` lands its steps on them.

    Notes
    -----
    Interpolation: each matrix entry is the trigonometric interpolant of its
    ``N`` samples (spectrally accurate for the smooth periodic matrices of
    this model; convergence in ``N`` is shown in ``tests/test_linearize.py``).
    """

    period: float
    times: np.ndarray
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    kp: float = 0.0
    kd: float = 0.0
    coordinates: tuple = ()
    hub_free: bool = True
    reference: str = "periodic"
    orbit_residual: float = math.nan
    elements: int = 0
    fd_step: float = math.nan
    wall_time: float = 0.0
    B: Optional[np.ndarray] = None
    B_t: Optional[np.ndarray] = None
    drive_names: tuple = ()
    basis: Optional[np.ndarray] = None
    basis_t: Optional[np.ndarray] = None
    breakpoints: tuple = ()

    def __post_init__(self) -> None:
        for name in ("M", "C", "K"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.ndim != 3 or a.shape[1] != a.shape[2] or a.shape[0] != np.size(self.times):
                raise ValueError(f"{name} must have shape (samples, n, n), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{name} contains NaN or inf")
            object.__setattr__(self, name, a)
        if not (self.M.shape == self.C.shape == self.K.shape):
            raise ValueError(f"M, C, K must have equal shape, got {self.M.shape}, {self.C.shape}, {self.K.shape}")
        if not (math.isfinite(self.period) and self.period > 0):
            raise ValueError(f"period must be finite and > 0, got {self.period!r}")
        if self.B is not None:
            for name in ("B", "B_t"):
                a = np.asarray(getattr(self, name), dtype=float)
                if a.ndim != 3 or a.shape[:2] != self.M.shape[:2]:
                    raise ValueError(f"{name} must have shape (samples, n, drives), got {a.shape}")
                object.__setattr__(self, name, a)
            if len(self.drive_names) != self.B.shape[2]:
                raise ValueError(f"{self.B.shape[2]} drives but {len(self.drive_names)} drive names")

    @property
    def drives(self) -> int:
        """Number of drives (columns of ``B``); 1 for the hand-derived hub."""
        return 1 if self.B is None else int(self.B.shape[2])

    def gains(self, values: "float | Sequence[float]", name: str) -> np.ndarray:
        """One gain per drive from a scalar (all drives) or a sequence (checked >= 0, finite)."""
        v = np.atleast_1d(np.asarray(values, dtype=float)).ravel()
        if v.size == 1:
            v = np.full(self.drives, float(v[0]))
        if v.size != self.drives:
            raise ValueError(f"{name}: one value per drive ({self.drives}) or one for all, got {v.size}")
        if not (np.all(np.isfinite(v)) and np.all(v >= 0)):
            raise ValueError(f"{name} must be finite and >= 0, got {values!r}")
        return v

    @property
    def size(self) -> int:
        """Number ``n`` of second-order coordinates (state size ``2 n``)."""
        return int(self.M.shape[1])

    @property
    def samples(self) -> int:
        """Number of samples per period."""
        return int(self.M.shape[0])

    def _trig_table(self) -> np.ndarray:
        """Real Fourier table ``[Re c; Im c]`` of the stacked ``(M, C, K)`` samples, shape
        ``(2 (N/2 + 1), 3 n^2)``, with the weights of :func:`linearize.fourier.trig_interpolate`
        (1, 2, ..., 2, 1); formed once per system (a propagation evaluates ``P`` at hundreds of
        times in chunks: one FFT of the samples instead of three per call)."""
        table = self.__dict__.get("_table")
        if table is None:
            N = self.samples
            c = np.fft.rfft(np.stack([self.M, self.C, self.K], axis=1), axis=0) / N
            w = np.full(N // 2 + 1, 2.0)
            w[0] = w[-1] = 1.0
            c = (c * w[:, None, None, None]).reshape(N // 2 + 1, -1)
            table = np.ascontiguousarray(np.concatenate([c.real, c.imag]))
            object.__setattr__(self, "_table", table)  # a cache, not a field (replace() drops it)
        return table

    @property
    def grid(self) -> Optional[PiecewiseGrid]:
        """The piecewise sampling of the orbit (:class:`~linearize.piecewise.PiecewiseGrid`) when it was
        sampled piece by piece (:attr:`breakpoints`); ``None`` for equispaced samples."""
        if not self.breakpoints:
            return None
        grid = self.__dict__.get("_grid")
        if grid is None:
            grid = PiecewiseGrid(self.period, self.breakpoints, self.samples)
            if not np.allclose(grid.times, self.times, rtol=0.0, atol=1e-12 * self.period):
                raise ValueError("breakpoints given, but the sample times are not their piecewise grid")
            object.__setattr__(self, "_grid", grid)  # a cache, not a field
        return grid

    def matrices(self, times: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Interpolated ``(M, C, K)`` at ``times``, each of shape ``(m, n, n)``.

        :func:`linearize.fourier.trig_interpolate` of each, in real arithmetic
        (``sum_k a_k cos(k w t) - b_k sin(k w t)``: one real product for the three); with
        :attr:`breakpoints`, piece by piece the polynomial through the piece's samples
        (:meth:`~linearize.piecewise.PiecewiseGrid.interpolate`: ``P`` may jump at a breakpoint).
        """
        t = np.atleast_1d(np.asarray(times, dtype=float))
        grid = self.grid
        if grid is not None:
            out = grid.interpolate(np.stack([self.M, self.C, self.K], axis=1), t)
            return out[:, 0], out[:, 1], out[:, 2]
        k = np.arange(self.samples // 2 + 1)
        arg = (2.0 * np.pi / self.period) * np.outer(t, k)
        rows = np.concatenate([np.cos(arg), -np.sin(arg)], axis=1)
        out = (rows @ self._trig_table()).reshape(t.size, 3, self.size, self.size)
        return out[:, 0], out[:, 1], out[:, 2]

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        """First-order matrices ``P(t)`` at ``times``, shape ``(m, 2n, 2n)``."""
        M, C, K = self.matrices(times)
        return first_order_matrix(M, C, K)

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([float(t)]))[0]

    def _trace(self, t: np.ndarray) -> np.ndarray:
        """``tr P(t) = -tr(M^-1 C)(t)`` (only ``M`` and ``C`` interpolated, no ``P`` built)."""
        if self.grid is not None:
            M, C, _ = self.matrices(t)
        else:
            M = trig_interpolate(self.M, self.period, t)
            C = trig_interpolate(self.C, self.period, t)
        return -np.trace(np.linalg.solve(M, C), axis1=1, axis2=2)

    def trace_integral(self, points: int = TRACE_POINTS) -> float:
        """``int_0^T tr P dt = -int_0^T tr(M^-1 C) dt`` by the nested periodic trapezoidal rule
        (see :data:`TRACE_POINTS`; ``points``: the most points used).  Warns (``RuntimeWarning``)
        with the last change when two successive sums never agreed."""
        from stability.floquet import TRACE_RTOL

        T = self.period
        grid = self.grid
        if grid is not None:
            # piece by piece: the interpolant is a polynomial of degree m_j - 1 on piece j, and tr(M^-1 C)
            # a smooth function of it; Gauss-Legendre with 64 nodes per piece
            x, w = np.polynomial.legendre.leggauss(64)
            total = 0.0
            for a, b in zip(grid.edges[:-1], grid.edges[1:]):
                total += 0.5 * (b - a) * float(np.sum(w * self._trace(a + 0.5 * (b - a) * (x + 1.0))))
            return total
        K = TRACE_MIN_POINTS // 2
        tr = self._trace(np.arange(K) * (T / K))
        total, abs_total = float(np.sum(tr)), float(np.sum(np.abs(tr)))
        integral, change = total * T / K, math.inf
        while 2 * K <= int(points):
            new = self._trace((np.arange(K) + 0.5) * (T / K))
            total += float(np.sum(new))
            abs_total += float(np.sum(np.abs(new)))
            K *= 2
            previous, integral = integral, total * T / K
            change = abs(integral - previous)
            if change <= TRACE_RTOL * abs_total * T / K:
                return float(integral)
        warnings.warn(f"int tr P: the periodic trapezoidal rule did not converge in {K} points (last change "
                      f"{change:.1e}, relative {change / max(abs_total * T / K, 1e-300):.1e} > {TRACE_RTOL:.0e})",
                      RuntimeWarning, stacklevel=2)
        return float(integral)

    def with_gains(self, kp, kd) -> "LinearizedPeriodicSystem":
        """The same system with the PD gains replaced.

        Hand-derived single link: constant terms on the hub (Eq. 32).  Model-file
        linearisation: ``kp``, ``kd`` are one value per drive (or one for all),
        entering through ``B`` and ``B_t`` (see the attributes).
        """
        if self.B is not None:
            kp_new, kd_new = self.gains(kp, "kp"), self.gains(kd, "kd")
            dkp = kp_new - self.gains(self.kp, "kp")
            dkd = kd_new - self.gains(self.kd, "kd")
            K = self.K + np.einsum("kid,d,kjd->kij", self.B, dkp, self.B) + np.einsum("kid,d,kjd->kij", self.B, dkd, self.B_t)
            C = self.C + np.einsum("kid,d,kjd->kij", self.B, dkd, self.B)
            return replace(self, K=K, C=C, kp=tuple(float(x) for x in kp_new), kd=tuple(float(x) for x in kd_new))
        if not self.hub_free:
            raise ValueError("PD gains need the free hub coordinate (linearise with drive='free')")
        for name, v in (("kp", kp), ("kd", kd)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        K = self.K.copy()
        C = self.C.copy()
        K[:, 0, 0] += kp - self.kp
        C[:, 0, 0] += kd - self.kd
        return replace(self, K=K, C=C, kp=float(kp), kd=float(kd))

    def summary(self) -> dict:
        """JSON-ready summary (no matrices)."""
        return {
            "period": self.period,
            "samples": self.samples,
            "size": self.size,
            "kp": list(self.kp) if isinstance(self.kp, tuple) else self.kp,
            "kd": list(self.kd) if isinstance(self.kd, tuple) else self.kd,
            "drives": list(self.drive_names),
            "hub_free": self.hub_free,
            "reference": self.reference,
            "orbit_residual": self.orbit_residual,
            "elements": self.elements,
        }
