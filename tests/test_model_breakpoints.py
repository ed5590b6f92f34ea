"""A model file whose drive has acceleration jumps: piecewise sampling of the orbit and its linearisation.

The model (``tests/models/bang_bang_pendulum.py``): a pendulum hanging from a support whose height is
driven with a bang-bang acceleration (jumps at ``t1 = (sqrt 2 - 1) T / 2`` and ``T - t1``).  Its
linearisation about the hanging orbit is derived by hand in the model's docstring: the PD-controlled
support ``(m_s + m) y'' + kd y' + kp y = 0`` and the pendulum ``J_p th'' + c th' + m l (g + r'') th = 0``
with a piecewise-constant ``r''``.  The reference multipliers come from ``scipy.integrate.solve_ivp``
on that equation, integrated piece by piece (rtol 1e-12), cross-checked against the product of the
pieces' matrix exponentials (exact for constant coefficients).
"""
from __future__ import annotations

import importlib.util
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from linearize.analysis import _sampling_order, analyze
from linearize.fourier import differentiation_matrices, sample_times
from linearize.piecewise import MIN_NODES, PiecewiseGrid
from linearize.system import LinearizedPeriodicSystem
from stability.floquet import CONTRACT_RTOL

MODEL = Path(__file__).parent / "models" / "bang_bang_pendulum.py"
OMEGA, KP, KD = 2.0 * math.pi, 40.0, 3.0


def _module():
    spec = importlib.util.spec_from_file_location("bang_bang_pendulum", MODEL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _theta_matrix(mod, acc: float) -> np.ndarray:
    Jp = mod.INERTIA + mod.MASS * mod.LENGTH**2
    return np.array([[0.0, 1.0], [-mod.MASS * mod.LENGTH * (mod.GRAVITY + acc) / Jp, -mod.DAMPING / Jp]])


def _reference(jump_shift: float = 0.0) -> np.ndarray:
    """Multipliers of the hand-derived variational equation (``jump_shift``: move the jumps by this
    fraction of the period -- a wrong answer for the check to reject)."""
    mod = _module()
    T = 2.0 * math.pi / OMEGA
    _, (t1, t2), (A, B) = mod.support_motion(OMEGA)
    t1, t2 = t1 + jump_shift * T, t2 - jump_shift * T
    Ay = np.array([[0.0, 1.0], [-KP / (mod.SUPPORT_MASS + mod.MASS), -KD / (mod.SUPPORT_MASS + mod.MASS)]])
    pieces = [(0.0, t1, -A), (t1, t2, B), (t2, T, -A)]
    # solve_ivp piece by piece on the 2x2 matrix ODE Phi' = A(t) Phi
    Phi = np.eye(2)
    for a, b, acc in pieces:
        Ath = _theta_matrix(mod, acc)
        sol = solve_ivp(lambda t, y, M=Ath: (M @ y.reshape(2, 2)).ravel(), (a, b), Phi.ravel(), method="DOP853",
                        rtol=1e-12, atol=1e-14)
        Phi = sol.y[:, -1].reshape(2, 2)
    exact = expm(_theta_matrix(mod, -A) * (T - t2)) @ expm(_theta_matrix(mod, B) * (t2 - t1)) \
        @ expm(_theta_matrix(mod, -A) * t1)
    assert np.allclose(Phi, exact, rtol=1e-10, atol=1e-12)  # the two references agree
    return np.concatenate([np.linalg.eigvals(expm(Ay * T)), np.linalg.eigvals(Phi)])


def _errors(multipliers: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Relative distance of each reference multiplier to the nearest computed one."""
    return np.array([np.min(np.abs(multipliers - r)) / abs(r) for r in ref])


def _analyze(declare: bool):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = analyze(str(MODEL), OMEGA, kp=KP, kd=KD, declare=declare)
    return res, [str(w.message) for w in caught]


def test_declared_breakpoints_give_certified_multipliers_within_the_contract():
    res, _ = _analyze(declare=True)
    f = res.floquet
    T = 2.0 * math.pi / OMEGA
    t1 = _module().FRACTION * T
    assert res.orbit.breakpoints == pytest.approx((0.0, t1, T - t1))
    assert f.breakpoints == pytest.approx((t1, T - t1))  # the steps landed on them
    assert f.all_certified and all(f.certified)
    err = _errors(f.multipliers, _reference())
    assert np.max(err) <= CONTRACT_RTOL, err
    # the comparison can fail: the answer of a motion with its jumps 1 % of T away is far off
    assert np.max(_errors(f.multipliers, _reference(jump_shift=0.01))) > 100 * CONTRACT_RTOL


def test_undeclared_breakpoints_are_reported_not_certified():
    res, messages = _analyze(declare=False)
    f = res.floquet
    assert not f.all_certified and not any(f.certified)
    assert all("not smooth" in r for r in f.uncertified_reasons)
    assert any("declare its breakpoints" in m for m in messages)
    # and rightly so: the equispaced samples miss the jumps, the multipliers are off by more than 1e-6
    assert np.max(_errors(f.multipliers, _reference())) > 10 * CONTRACT_RTOL


def test_sampling_order_separates_a_jump_from_a_smooth_matrix():
    T, N = 1.0, 32
    t = sample_times(T, N)
    smooth = np.exp(np.sin(2 * math.pi * t))[:, None, None] * np.ones((1, 2, 2))
    jump = np.where((t % T) < 0.3, 1.0, 2.0)[:, None, None] * np.ones((1, 2, 2))
    eye = np.broadcast_to(np.eye(2), (N, 2, 2))

    def lin(K):
        return LinearizedPeriodicSystem(period=T, times=t, M=eye, C=0.1 * eye, K=K)

    q_smooth, _, _ = _sampling_order(lin(smooth))
    q_jump, e_jump, name = _sampling_order(lin(jump))
    assert q_smooth > 8.0 and q_jump < 1.0 and name == "K" and e_jump > 0.1


def _c1_piecewise_quadratic(T: float, t1: float):
    """``r`` with ``r'' = -1`` on ``[0, t1)`` and ``[T - t1, T)``, ``+b`` between: C^1 and T-periodic."""
    b = 2.0 * t1 / (T - 2.0 * t1)
    y1 = -0.5 * t1 * t1
    y2 = y1 - t1 * (T - 2.0 * t1) + 0.5 * b * (T - 2.0 * t1) ** 2

    def r(t):
        x = np.mod(t, T)
        u, w = x - t1, x - (T - t1)
        value = np.where(x < t1, -0.5 * x * x, np.where(x < T - t1, y1 - t1 * u + 0.5 * b * u * u,
                                                           y2 + t1 * w - 0.5 * w * w))
        acc = np.where(x < t1, -1.0, np.where(x < T - t1, b, -1.0))
        return value, acc

    return r


def test_piecewise_grid_differentiates_a_c1_motion_exactly_and_fourier_does_not():
    T, t1 = 2.0, 0.37
    r = _c1_piecewise_quadratic(T, t1)
    g = PiecewiseGrid(T, [t1, T - t1], 24)
    assert g.times[0] > 0.0 and np.all(np.diff(g.times) > 0) and len(g.counts) == 3
    value, acc = r(g.times)
    assert np.max(np.abs(g.D2 @ value - acc)) < 1e-10
    # a smooth function is reproduced spectrally between the nodes (value and derivatives)
    tt = np.linspace(0.0, T, 501)
    errors = []
    for K in (16, 32, 48):
        gk = PiecewiseGrid(T, [t1, T - t1], K)
        f = np.exp(np.sin(2 * math.pi * gk.times / T))
        errors.append(np.max(np.abs(gk.smooth(f, tt) - np.exp(np.sin(2 * math.pi * tt / T)))))
    assert errors[2] < 1e-8 < errors[0] and errors[1] < errors[0] / 100
    # the check can fail: spectral differentiation of the same motion on 24 equispaced samples
    te = sample_times(T, 24)
    _, D2 = differentiation_matrices(T, 24)
    value_e, acc_e = r(te)
    assert np.max(np.abs(D2 @ value_e - acc_e)) > 1e-2


def test_piecewise_interpolation_jumps_and_is_exact_for_polynomials_on_each_piece():
    T = 1.0
    g = PiecewiseGrid(T, [0.4], 2 * MIN_NODES + 2)
    f = np.where(g.times < 0.4, 1.0 + g.times**2, -3.0 + g.times)
    tt = np.array([0.0, 0.1, 0.3999999, 0.4, 0.7, 0.9999])
    expected = np.where(tt < 0.4, 1.0 + tt**2, -3.0 + tt)
    assert np.max(np.abs(g.interpolate(f, tt) - expected)) < 1e-12
    with pytest.raises(ValueError, match="samples"):
        PiecewiseGrid(T, [0.1, 0.2, 0.3], 3 * MIN_NODES)  # four pieces need 4 * MIN_NODES


def test_linearised_system_rejects_breakpoints_that_are_not_its_grid():
    T, N = 1.0, 16
    eye = np.broadcast_to(np.eye(1), (N, 1, 1))
    lin = LinearizedPeriodicSystem(period=T, times=sample_times(T, N), M=eye, C=eye, K=eye, breakpoints=(0.0, 0.5))
    with pytest.raises(ValueError, match="piecewise grid"):
        lin.evaluate(np.array([0.1]))


def test_hill_is_never_chosen_nor_run_on_a_piecewise_linearisation():
    """Hill's method interpolates equispaced samples trigonometrically: on a piecewise-sampled
    linearisation (Gauss nodes per piece, coefficients that jump) that interpolant is wrong, so the
    engine rule must not offer it and the engine and the tuning plant refuse it by name."""
    from linearize.hill_plant import HillModelPlant, drive_gain_family
    from stability.engines.hill import HillEngine
    from stability.engines.rule import system_properties

    res, _ = _analyze(declare=True)
    lin = res.linearization
    assert lin.breakpoints
    assert not system_properties(lin).trigonometric
    with pytest.raises(ValueError, match="breakpoints"):
        HillEngine().run(lin, None, 1e-6, targets=res.floquet.multipliers[:1])
    with pytest.raises(ValueError, match="breakpoints"):
        HillModelPlant(lin, res.orbit)
    with pytest.raises(ValueError, match="breakpoints"):
        drive_gain_family(lin)
    # the same matrices without the declaration would be offered to Hill: the check can fail
    bare = type("Bare", (), {"period": lin.period, "M": lin.M, "C": lin.C, "K": lin.K,
                             "evaluate": staticmethod(lin.evaluate)})()
    assert system_properties(bare).trigonometric


def test_rounding_noise_damping_is_not_a_non_smooth_linearisation():
    """An undamped model's C is rounding noise (1e-15 of the critical damping scale): its interpolation
    error relative to its own size is O(1), which must not read as a non-smooth motion; a C with a
    genuine kink at the same size relative to critical damping as K's is still caught."""
    import types

    from linearize.analysis import SAMPLING_MIN_ORDER, _sampling_order

    N, T = 32, 1.0
    t = np.arange(N) * (T / N)
    rng = np.random.default_rng(3)
    M = np.broadcast_to(np.diag([0.075, 0.075, 0.01]), (N, 3, 3)).copy()
    K = (2.4 + 0.5 * np.cos(2 * np.pi * t))[:, None, None] * np.eye(3)
    noise = 3e-15 * rng.standard_normal((N, 3, 3))
    lin = types.SimpleNamespace(samples=N, period=T, times=t, M=M, C=noise, K=K)
    q, e, name = _sampling_order(lin)
    assert not (q < SAMPLING_MIN_ORDER and e > 1e-9), (q, e, name)
    # a kinked damping |sin(2 pi t)| at 10 % of critical damping is reported as non-smooth
    kink = 0.04 * np.abs(np.sin(2 * np.pi * t))[:, None, None] * np.eye(3)
    q, e, name = _sampling_order(types.SimpleNamespace(samples=N, period=T, times=t, M=M, C=kink, K=K))
    assert name == "C" and q < SAMPLING_MIN_ORDER and e > 1e-6
