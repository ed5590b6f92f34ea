"""Accurate tiny multipliers by QR sweeps (``small_multipliers="qr"``) against analytic oracles."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mbs_models.reduced import ReducedModel
from stability import floquet


def _lyapunov_transformed(A: np.ndarray, T: float):
    """P = L' L^-1 + L A L^-1 with a T-periodic, invertible L(t): multipliers exp(eig(A) T)."""
    n = A.shape[0]
    w = 2 * math.pi / T
    B = np.random.default_rng(7).standard_normal((n, n)) * 0.3

    def L(t):
        return np.eye(n) + 0.5 * math.sin(w * t) * B

    def Ld(t):
        return 0.5 * w * math.cos(w * t) * B

    def P(t):
        Li = np.linalg.inv(L(t))
        return Ld(t) @ Li + L(t) @ A @ Li

    return P


@pytest.mark.parametrize("method", ["magnus6", "magnus4"])
def test_stiff_periodic_system_small_moduli_exact(method):
    # eigenvalues -3000, -40, -1 +- 3i: multipliers down to exp(-3000) = 1e-1303 (underflow)
    A = np.array([[-3000.0, 1.0, 0.0, 0.0], [0.0, -40.0, 2.0, 0.0], [0.0, 0.0, -1.0, 3.0], [0.0, 0.0, -3.0, -1.0]])
    T = 1.0
    res = floquet(_lyapunov_transformed(A, T), period=T, method=method, small_multipliers="qr")
    expected = np.sort(np.real(np.linalg.eigvals(A)) * T)[::-1]  # ln|rho| = Re(lambda) T
    # the pair is exact to the method's accuracy (~1e-9); the stiff ones relative to themselves
    np.testing.assert_allclose(res.log_moduli, expected, rtol=1e-8, atol=1e-7)
    assert np.all(res.reliable_digits > 6)
    assert res.liouville_source == "multipliers" and res.liouville_residual < 1e-8


def test_flag_mode_marks_them_unreliable():
    A = np.diag([-3000.0, -1.0])
    res = floquet(lambda t: A, period=1.0)
    assert res.reliable_digits[-1] == 0 and res.liouville_source == "propagators"


def test_controlled_manipulator_liouville_on_all_multipliers():
    """Table 3 gains (paper p. 489), Omega = 2pi: the tiny multipliers (~1e-1378) now carry Liouville."""
    res = floquet(ReducedModel(2 * math.pi, 37.1617, 29.2410), small_multipliers="qr")
    assert res.liouville_source == "multipliers"
    assert abs(np.sum(res.log_moduli) - res.trace_integral) < 1e-8 * abs(res.trace_integral)
    assert res.log_moduli[-1] < -3000  # far below what a float can hold as a number
    assert res.spectral_radius == pytest.approx(0.3, rel=1e-4)


def test_qr_needs_a_factor_method():
    with pytest.raises(ValueError, match="factor method"):
        floquet(lambda t: np.eye(2), period=1.0, method="paper", small_multipliers="qr")
    with pytest.raises(ValueError, match="small_multipliers"):
        floquet(lambda t: np.eye(2), period=1.0, small_multipliers="schur")
