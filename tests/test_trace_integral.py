"""``LinearizedPeriodicSystem.trace_integral`` (nested periodic trapezoidal rule, checked) against closed forms.

``n = 1``, ``M(t) = a + cos(w t)``, ``C = 1``: ``int_0^T tr P dt = -int_0^T dt / (a + cos w t) = -T / sqrt(a^2 - 1)``
(a standard integral).  ``M`` is sampled at 16 points and trigonometrically interpolated, exact for
``a + cos``, so the only error is the rule's.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from linearize.system import LinearizedPeriodicSystem

T = 0.5


def _system(a: float) -> LinearizedPeriodicSystem:
    times = np.arange(16) * (T / 16)
    M = (a + np.cos(2 * math.pi * times / T))[:, None, None]
    return LinearizedPeriodicSystem(period=T, times=times, M=M, C=np.ones_like(M), K=np.ones_like(M))


def test_trace_integral_equals_closed_form():
    """a = 3: the trapezoidal error is ~ (a - sqrt(a^2 - 1))^K, converged long before 4096 points; the result
    meets the closed form to the rule's tolerance (TRACE_RTOL = 1e-13 of int |tr|, plus summation rounding)."""
    a = 3.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        value = _system(a).trace_integral()
    exact = -T / math.sqrt(a * a - 1.0)
    assert abs(value - exact) <= 2e-13 * abs(exact)


def test_unconverged_rule_warns_instead_of_returning_silently():
    """a = 1 + 1e-6: the integrand is nearly singular (error factor (a - sqrt(a^2 - 1))^K ~ exp(-1.4e-3 K)),
    so 512 points cannot reach 1e-13; the rule warns and the value is indeed off (the former fixed 512-point
    rule returned such a value without a word)."""
    a = 1.0 + 1e-6
    sys_ = _system(a)
    with pytest.warns(RuntimeWarning, match="did not converge"):
        value = sys_.trace_integral(points=512)
    exact = -T / math.sqrt(a * a - 1.0)
    assert abs(value - exact) > 1e-6 * abs(exact)
