"""Periodic matrices and periodic second-order systems.

A *periodic matrix* here is any object ``P`` with

* ``P(t) -> ndarray (n, n)`` for a scalar time ``t``, and
* optionally ``P.period`` (the period ``T > 0``), and
* optionally ``P.evaluate(times) -> ndarray (m, n, n)``, a vectorised
  evaluation used by the fast Floquet methods.

:class:`SecondOrderPeriodicSystem` is the periodic mass/damping/stiffness
system ``M(t) y'' + C(t) y' + K(t) y = 0`` of the paper's Eq. (25); the one
place where the first-order matrix ``P(t) = [[0, I], [-M^-1 K, -M^-1 C]]``
(paper Eq. 5) is built is :func:`first_order_matrix`.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np

__all__ = [
    "PeriodicMatrixFunction",
    "SecondOrderPeriodicSystem",
    "first_order_matrix",
    "check_period",
]

MatrixFunction = Callable[[float], np.ndarray]

#: Reciprocal condition number below which a mass matrix is called singular.
SINGULAR_MASS_RCOND = 1e-13


def check_period(period: Any, name: str = "period") -> float:
    """Return ``period`` as a float, or raise ``ValueError`` if it is not finite and > 0."""
    if isinstance(period, (bool, str, bytes)):
        raise ValueError(f"{name} must be a real number, got {period!r}")
    try:
        value = float(period)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {period!r}") from None
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be finite and > 0, got {period!r}")
    return value


def first_order_matrix(
    M: np.ndarray, C: np.ndarray, K: np.ndarray, *, mass_inverse: Optional[np.ndarray] = None
) -> np.ndarray:
    """First-order system matrix of ``M y'' + C y' + K y = 0``.

    Parameters
    ----------
    M, C, K : ndarray, shape (..., f, f)
        Mass, damping and stiffness matrices, possibly stacked over leading
        axes (e.g. over sample times).

    Returns
    -------
    P : ndarray, shape (..., 2f, 2f)
        ``P = [[0, I], [-M^-1 K, -M^-1 C]]`` for the state ``x = [y, y']``
        (paper Eqs. 4-5).

    Raises
    ------
    ValueError
        If a mass matrix is singular (reciprocal condition number below
        :data:`SINGULAR_MASS_RCOND`) or an entry is not finite.

    Notes
    -----
    Sign convention: ``K`` and ``C`` are the matrices on the *left-hand side*
    of the equation of motion.  For a force vector ``f(q, q', t)`` on the
    right-hand side (Exudyn's convention ``M q'' = f``) this means
    ``K = -df/dq`` and ``C = -df/dq'``.  This is the only function in the
    package that forms ``P`` from ``(M, C, K)``.
    """
    M = np.asarray(M, dtype=float)
    C = np.asarray(C, dtype=float)
    K = np.asarray(K, dtype=float)
    if M.shape[-1] != M.shape[-2] or M.shape != C.shape or M.shape != K.shape:
        raise ValueError(
            f"M, C, K must be square and of equal shape, got {M.shape}, {C.shape}, {K.shape}"
        )
    for name, mat in (("M", M), ("C", C), ("K", K)):
        if not np.all(np.isfinite(mat)):
            raise ValueError(f"{name}(t) contains NaN or inf")
    f = M.shape[-1]
    if mass_inverse is not None:
        MinvK = mass_inverse @ K
        MinvC = mass_inverse @ C
    elif f >= LU_MIN_SIZE:
        MinvK, MinvC = _solve_mass_lu(M, K, C)
    else:
        cond = np.linalg.cond(M)
        if np.any(~np.isfinite(cond)) or np.any(1.0 / cond < SINGULAR_MASS_RCOND):
            raise ValueError(
                f"mass matrix M(t) is singular (condition number {np.max(cond):.3g})"
            )
        if M.ndim == 3 and M.shape[0] > 1:
            # a uniformly scaled M has condition number 1 however small it gets: compare
            # each sample's size with the largest over the samples
            size = np.linalg.norm(M, ord=2, axis=(1, 2))
            if np.any(size < SINGULAR_MASS_RCOND * np.max(size)):
                raise ValueError("mass matrix M(t) is singular at some sample time (it vanishes there)")
        MinvK = np.linalg.solve(M, K)
        MinvC = np.linalg.solve(M, C)
    P = np.zeros(M.shape[:-2] + (2 * f, 2 * f))
    P[..., :f, f:] = np.eye(f)
    P[..., f:, :f] = -MinvK
    P[..., f:, f:] = -MinvC
    return P


#: Mass matrices of at least this size are factorised once per time (LAPACK ``getrf``) and
#: checked with the 1-norm condition estimate of that factorisation (``gecon``, O(f^2)), instead
#: of two SVDs (``cond`` and the 2-norm) and two solves per time: at f = 263 (64 ANCF elements)
#: 6 ms instead of 22 ms per time.  Below it the stacked numpy calls are cheaper than a loop.
LU_MIN_SIZE = 32


def _solve_mass_lu(M: np.ndarray, K: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(M^-1 K, M^-1 C)`` for stacks of mass matrices, one LU per matrix, singular ones rejected.

    Criterion (same threshold :data:`SINGULAR_MASS_RCOND` as the SVD path): the reciprocal
    1-norm condition estimate of LAPACK's ``gecon`` (its ``||M^-1||_1`` is a lower bound, in
    practice within a factor 3, Higham 2002, Sec. 15.3; ``kappa_1`` and ``kappa_2`` agree within
    a factor ``f``), so the test is the SVD path's up to a factor ``3 f`` in the threshold: it
    guards against singular and vanishing mass matrices, it does not certify accuracy.  The size
    check compares Frobenius norms (within ``sqrt(f)`` of the 2-norms).
    """
    from scipy.linalg import lapack

    lead = M.shape[:-2]
    f = M.shape[-1]
    Ms = M.reshape((-1, f, f))
    KC = np.concatenate([K, C], axis=-1).reshape((-1, f, 2 * f))
    if Ms.shape[0] > 1:
        size = np.sqrt(np.einsum("kij,kij->k", Ms, Ms))
        if np.any(size < SINGULAR_MASS_RCOND * np.max(size)):
            raise ValueError("mass matrix M(t) is singular at some sample time (it vanishes there)")
    out = np.empty_like(KC)
    for k in range(Ms.shape[0]):
        lu, piv, info = lapack.dgetrf(Ms[k])
        rcond = 0.0
        if info == 0:
            rcond, _ = lapack.dgecon(lu, float(np.abs(Ms[k]).sum(axis=0).max()))
        if not rcond >= SINGULAR_MASS_RCOND:
            cond = 1.0 / rcond if rcond > 0 else math.inf
            raise ValueError(f"mass matrix M(t) is singular (condition number estimate {cond:.3g})")
        out[k], _ = lapack.dgetrs(lu, piv, KC[k])
    out = out.reshape(lead + (f, 2 * f))
    return out[..., :f], out[..., f:]


@dataclass(frozen=True)
class SecondOrderPeriodicSystem:
    """T-periodic system ``M(t) y'' + C(t) y' + K(t) y = 0``.

    Parameters
    ----------
    period : float
        The period ``T > 0``.
    mass, damping, stiffness : callable
        ``t -> (f, f)`` arrays.  If they accept an array of times of shape
        ``(m,)`` and return ``(m, f, f)`` set ``vectorized=True``.
    vectorized : bool
        Whether the three callables accept arrays of times.
    name : str
        A label carried into results.
    breakpoints : tuple of float
        Times in ``[0, T)`` where ``M, C, K`` or a derivative jump (switching times, the corners of
        a trapezoidal velocity profile); :func:`stability.floquet.floquet` lands its steps on them
        so that each smooth piece converges at the method's order.  Default: none (smooth).

    Notes
    -----
    The object is itself a periodic matrix: ``sys(t)`` returns ``P(t)`` from
    :func:`first_order_matrix`, ``sys.evaluate(times)`` a stack of them.
    """

    period: float
    mass: MatrixFunction
    damping: MatrixFunction
    stiffness: MatrixFunction
    vectorized: bool = False
    name: str = "second-order system"
    breakpoints: tuple = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "period", check_period(self.period))
        try:
            points = tuple(float(b) for b in self.breakpoints)
        except (TypeError, ValueError):
            raise ValueError(f"breakpoints must be a sequence of times, got {self.breakpoints!r}") from None
        if not all(math.isfinite(b) and 0.0 <= b < self.period for b in points):
            raise ValueError(f"breakpoints must be finite times in [0, period), got {self.breakpoints!r}")
        object.__setattr__(self, "breakpoints", points)

    def matrices(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M, C, K)`` stacked over ``times`` (shape ``(m, f, f)`` each)."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if self.vectorized:
            return (
                np.asarray(self.mass(times), dtype=float),
                np.asarray(self.damping(times), dtype=float),
                np.asarray(self.stiffness(times), dtype=float),
            )
        M = np.array([self.mass(t) for t in times], dtype=float)
        C = np.array([self.damping(t) for t in times], dtype=float)
        K = np.array([self.stiffness(t) for t in times], dtype=float)
        return M, C, K

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        """First-order matrices ``P(t)`` stacked over ``times``, shape ``(m, 2f, 2f)``."""
        return first_order_matrix(*self.matrices(times))

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([float(t)]))[0]


class PeriodicMatrixFunction:
    """Wrap a user callable ``t -> P(t)`` with validation and vectorised evaluation.

    Parameters
    ----------
    func : callable or periodic matrix object
        ``t -> (n, n)`` array; if it has ``evaluate(times)`` that is used for
        stacks of times.
    period : float, optional
        Period ``T``; taken from ``func.period`` when omitted.

    Raises
    ------
    ValueError
        If no period is given or known, the period is not positive, or
        ``func`` returns a non-square, non-finite or inconsistently shaped
        matrix.
    """

    def __init__(self, func: Any, period: Optional[float] = None) -> None:
        if not callable(func):
            raise ValueError(f"P must be callable (t -> (n, n) array), got {type(func).__name__}")
        own = getattr(func, "period", None)
        if period is None:
            period = own
            if period is None:
                raise ValueError("period is required: P carries no .period attribute")
        elif own is not None and abs(check_period(period) - check_period(own)) > 1e-12 * check_period(own):
            raise ValueError(f"period = {period!r} conflicts with the period {own!r} that P carries")
        self.func = func
        self.period = check_period(period)
        self._vectorised = callable(getattr(func, "evaluate", None))
        P0 = self._check(self._as_real(func(0.0), "P(0)")[None], "P(0)")
        self.n = P0.shape[-1]
        self._broadcasts = not self._vectorised and self._accepts_arrays(P0[0])

    def _accepts_arrays(self, P0: np.ndarray) -> bool:
        """Whether the plain callable also maps an array of times to a stack ``(m, n, n)`` (numpy
        code often does): tried once on two times and compared with the scalar calls."""
        probe = np.array([0.0, 0.371 * self.period])
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                stack = np.asarray(self.func(probe))
                second = np.asarray(self.func(float(probe[1])), dtype=float)
        except Exception:  # noqa: BLE001 - any failure means: call it per time
            return False
        if stack.shape != (2, self.n, self.n) or np.iscomplexobj(stack) or stack.dtype == object:
            return False
        return bool(np.array_equal(stack[0], P0) and np.allclose(stack[1], second, rtol=1e-14, atol=0.0))

    @staticmethod
    def _as_real(value: Any, what: str) -> np.ndarray:
        arr = np.asarray(value)
        if np.iscomplexobj(arr):
            raise ValueError(f"{what} must be real-valued; got a complex matrix (write it as a real system "
                             f"of twice the size)")
        try:
            return np.asarray(arr, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{what} must be a real (n, n) array, got {type(value).__name__}") from None

    def _check(self, P: np.ndarray, what: str) -> np.ndarray:
        if P.ndim != 3 or P.shape[-1] != P.shape[-2] or P.shape[-1] == 0:
            raise ValueError(f"{what} must be a square (n, n) matrix, got shape {P.shape[1:]}")
        if hasattr(self, "n") and P.shape[-1] != self.n:
            raise ValueError(f"{what} has shape {P.shape[1:]}, expected ({self.n}, {self.n})")
        if not np.isfinite(P).all():
            raise ValueError(f"{what} contains NaN or inf")
        return P

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([t]))[0]

    def evaluate(self, times: np.ndarray) -> np.ndarray:
        """Stack of ``P(t)`` for ``times`` (shape ``(m, n, n)``), validated."""
        times = np.asarray(times, dtype=float)
        if self._vectorised:
            P = self._as_real(self.func.evaluate(times), "P(t)")
        elif self._broadcasts and times.ndim == 1:
            P = self._as_real(self.func(times), "P(t)")
            if P.shape != (times.size, self.n, self.n):
                P = self._loop(times)
        else:
            P = self._loop(times)
        return self._check(P, "P(t)")

    def _loop(self, times: np.ndarray) -> np.ndarray:
        """One call per time; the values converted to one stack at once (the per-value checks only
        when that fails or a value is complex)."""
        f = self.func
        values = [f(t) for t in times.tolist()]
        if values and not np.iscomplexobj(values[0]):
            try:
                return np.array(values, dtype=float)
            except (TypeError, ValueError):
                pass
        return np.array([self._as_real(v, "P(t)") for v in values])

