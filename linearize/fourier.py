"""Trigonometric interpolation and spectral differentiation of periodic samples.

Samples ``y_k = y(t_k)`` at ``t_k = k T / N`` (``k = 0..N-1``, ``N`` even)
define the trigonometric interpolant of degree ``N/2``; for smooth periodic
functions it converges spectrally in ``N``.  The Nyquist term is the cosine
``Re(c_{N/2}) cos(N pi t / T)`` (real, symmetric convention).
"""
from __future__ import annotations

import numpy as np

__all__ = ["sample_times", "trig_interpolate", "TrigInterpolant", "differentiation_matrices",
           "antiperiodic_differentiation_matrices", "antiperiodic_interpolate"]


def _check_samples(N: int) -> int:
    if isinstance(N, bool) or int(N) != N or N < 4 or N % 2:
        raise ValueError(f"number of samples must be an even integer >= 4, got {N!r}")
    return int(N)


def sample_times(period: float, N: int) -> np.ndarray:
    """Equispaced sample times ``k T / N``, ``k = 0..N-1``."""
    N = _check_samples(N)
    return np.arange(N) * (float(period) / N)


def trig_interpolate(samples: np.ndarray, period: float, times: np.ndarray | float) -> np.ndarray:
    """Evaluate the trigonometric interpolant of ``samples`` (axis 0) at ``times``.

    Parameters
    ----------
    samples : ndarray, shape (N, ...)
        Values at ``sample_times(period, N)``.
    period : float
        The period ``T``.
    times : float or ndarray, shape (m,)
        Evaluation times (any real values; the interpolant is T-periodic).

    Returns
    -------
    ndarray, shape (m, ...) (or ``samples.shape[1:]`` for a scalar time)
    """
    y = np.asarray(samples, dtype=float)
    N = _check_samples(y.shape[0])
    scalar = np.ndim(times) == 0
    t = np.atleast_1d(np.asarray(times, dtype=float))
    c = np.fft.rfft(y, axis=0) / N  # (N/2+1, ...)
    w = np.full(N // 2 + 1, 2.0)
    w[0] = 1.0
    w[-1] = 1.0
    k = np.arange(N // 2 + 1)
    phase = np.exp(1j * 2.0 * np.pi / period * np.outer(t, k)) * w  # (m, N/2+1)
    flat = c.reshape(c.shape[0], -1)
    out = np.real(phase @ flat).reshape((t.size,) + y.shape[1:])
    return out[0] if scalar else out


class TrigInterpolant:
    """The interpolant of :func:`trig_interpolate` with its coefficients computed once.

    For a callable evaluated at one time per call many thousands of times (an Exudyn load user
    function: one call per Newton iteration of every step), :func:`trig_interpolate` repeats the
    FFT of the samples at every call; here a scalar time costs ``N/2 + 1`` cosines and sines.

    Parameters
    ----------
    samples : ndarray, shape (N,)
        Values at ``sample_times(period, N)`` (scalar-valued samples).
    period : float
        The period ``T``.
    """

    def __init__(self, samples: np.ndarray, period: float) -> None:
        y = np.asarray(samples, dtype=float)
        if y.ndim != 1:
            raise ValueError(f"samples must be one-dimensional, got shape {y.shape}")
        N = _check_samples(y.shape[0])
        self.samples = y
        self.period = float(period)
        c = np.fft.rfft(y) / N
        w = np.full(N // 2 + 1, 2.0)
        w[0] = 1.0
        w[-1] = 1.0
        # Re(w_k c_k exp(i k theta)) = a_k cos(k theta) - b_k sin(k theta)
        self._a = w * c.real
        self._b = w * c.imag
        self._k = np.arange(N // 2 + 1, dtype=float)
        self._omega = 2.0 * np.pi / self.period

    def __call__(self, t: float | np.ndarray) -> float | np.ndarray:
        """Value at ``t`` (float for a scalar time, else an array of the shape of ``t``)."""
        if np.ndim(t) == 0:
            kt = self._k * (self._omega * float(t))
            return float(self._a @ np.cos(kt) - self._b @ np.sin(kt))
        return trig_interpolate(self.samples, self.period, t)

    def __getstate__(self) -> dict:
        return {"samples": self.samples, "period": self.period}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["samples"], state["period"])


def differentiation_matrices(period: float, N: int) -> tuple[np.ndarray, np.ndarray]:
    """First and second spectral differentiation matrices ``D1, D2`` (N x N).

    ``D1 @ y`` and ``D2 @ y`` are the derivatives of the trigonometric
    interpolant at the sample times (``D1`` drops the Nyquist sine, which
    vanishes at the samples; ``D2`` keeps the Nyquist cosine).
    """
    N = _check_samples(N)
    k = np.fft.fftfreq(N, d=1.0 / N)
    omega = 2.0 * np.pi / period
    ik = 1j * k * omega
    ik1 = ik.copy()
    ik1[N // 2] = 0.0
    F = np.fft.fft(np.eye(N), axis=0)
    D1 = np.real(np.fft.ifft(ik1[:, None] * F, axis=0))
    k2 = -(k * omega) ** 2
    k2[N // 2] = -((N // 2) * omega) ** 2
    D2 = np.real(np.fft.ifft(k2[:, None] * F, axis=0))
    return D1, D2


def antiperiodic_differentiation_matrices(period: float, N: int) -> tuple[np.ndarray, np.ndarray]:
    """``D1, D2`` (N x N) for T-antiperiodic functions, ``y(t + T) = -y(t)`` (odd harmonics of
    ``pi / T``: e.g. the Euler parameters of a body that makes one whole turn per period).

    Maths: such a ``y`` is 2T-periodic; its 2N samples over ``[0, 2T)`` are ``[y; -y]``, so the
    2T-periodic matrices ``D`` (:func:`differentiation_matrices` with ``2T, 2N``) act on the first
    half as ``D[:N, :N] - D[:N, N:]`` (exact for the odd harmonics ``1, 3, ..., N - 1`` of ``pi/T``;
    the 2T Nyquist harmonic ``N`` is even, absent from an antiperiodic function).
    """
    N = _check_samples(N)
    D1, D2 = differentiation_matrices(2.0 * period, 2 * N)
    return D1[:N, :N] - D1[:N, N:], D2[:N, :N] - D2[:N, N:]


def antiperiodic_interpolate(samples: np.ndarray, period: float, times: np.ndarray | float) -> np.ndarray:
    """The interpolant of T-antiperiodic samples (``y(t + T) = -y(t)``) at ``times``
    (:func:`trig_interpolate` of ``[y; -y]`` over ``2T``)."""
    y = np.asarray(samples, dtype=float)
    return trig_interpolate(np.concatenate([y, -y], axis=0), 2.0 * period, times)
