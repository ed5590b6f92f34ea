"""Trigonometric interpolation (linearize.fourier) against closed-form trigonometric polynomials."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from linearize.fourier import TrigInterpolant, sample_times, trig_interpolate

T = 0.7
N = 16


def _poly(t):
    """A trigonometric polynomial of degree 5 < N/2 (interpolated exactly by N = 16 samples)."""
    th = 2 * math.pi * np.asarray(t) / T
    return 0.3 + np.cos(th) - 0.8 * np.sin(2 * th) + 0.25 * np.cos(5 * th + 0.4)


def test_interpolant_reproduces_a_trig_polynomial_between_the_samples():
    # exact for degree < N/2: only rounding, ~ N eps * max|coefficient| = 16 * 2.2e-16 * 1 ~ 4e-15; bound 1e-13
    f = TrigInterpolant(_poly(sample_times(T, N)), T)
    t = np.random.default_rng(3).uniform(-5, 5, 300)
    err = max(abs(f(float(s)) - float(_poly(s))) for s in t)
    assert err < 1e-13
    assert np.max(np.abs(f(t) - _poly(t))) < 1e-13  # array times take the FFT route


def test_scalar_fast_path_equals_trig_interpolate_and_survives_pickling():
    y = np.random.default_rng(4).normal(size=N)
    f = TrigInterpolant(y, T)
    g = pickle.loads(pickle.dumps(f))
    for s in np.linspace(-1.0, 2.0, 37):
        assert abs(f(float(s)) - trig_interpolate(y, T, float(s))) < 1e-13
        assert g(float(s)) == f(float(s))


def test_a_wrong_period_is_rejected_by_the_check():
    """The same samples read with another period miss the polynomial between the samples."""
    f = TrigInterpolant(_poly(sample_times(T, N)), 1.01 * T)
    t = np.random.default_rng(5).uniform(0, T, 50)
    assert max(abs(f(float(s)) - float(_poly(s))) for s in t) > 1e-3


def test_bad_samples():
    with pytest.raises(ValueError, match="even integer"):
        TrigInterpolant(np.ones(7), T)
    with pytest.raises(ValueError, match="one-dimensional"):
        TrigInterpolant(np.ones((8, 2)), T)
