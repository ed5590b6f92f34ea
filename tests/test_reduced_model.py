"""Tests of the paper's reduced one-mode model (:mod:`mbs_models.reduced`).

Oracles:

* the mode constants printed below Eq. (25) of the paper (p. 489) and an
  independent derivation of the clamped-free first mode written out here
  (frequency equation by ``brentq``, integrals by Gauss-Legendre quadrature,
  not the library's adaptive ``quad``);
* Eqs. (21)-(24) and (32) of the paper, written out by hand for the Table 1
  data at instants where ``sin q_a^R`` and ``dq_a^R/dt`` are known exactly.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from mbs_models.parameters import ManipulatorParameters
from mbs_models.reduced import (
    PAPER_MODE_CONSTANTS,
    ReducedModel,
    derived_mode_constants,
    mode_constants,
)

P1 = ManipulatorParameters()
L = 0.9
#: Printed below Eq. (25), p. 489.
PRINTED = {"C1": -0.704632, "D1": -0.460710, "m11": 0.899850, "k11_star": 16.955151, "X1": -1.9987}


# --------------------------------------------------------------------------- mode constants
def _independent_mode_constants(length: float) -> dict[str, float]:
    """First clamped-free bending mode, normalised to int X^2 = l, X(l) < 0."""
    bl = brentq(lambda b: math.cos(b) * math.cosh(b) + 1.0, 1.5, 2.5, xtol=1e-15, rtol=1e-15)
    b = bl / length
    s = (math.cosh(bl) + math.cos(bl)) / (math.sinh(bl) + math.sin(bl))
    # 80-point Gauss-Legendre: exact to rounding for these entire functions on [0, l]
    z, w = np.polynomial.legendre.leggauss(80)
    x = 0.5 * length * (z + 1.0)
    w = 0.5 * length * w
    phi = np.cosh(b * x) - np.cos(b * x) - s * (np.sinh(b * x) - np.sin(b * x))
    phi2 = b**2 * (np.cosh(b * x) + np.cos(b * x) - s * (np.sinh(b * x) + np.sin(b * x)))
    tip = math.cosh(bl) - math.cos(bl) - s * (math.sinh(bl) - math.sin(bl))
    c = math.sqrt(length / np.dot(w, phi**2)) * (-1.0 if tip > 0 else 1.0)
    return {
        "beta_l": bl,
        "C1": c * np.dot(w, phi),
        "D1": c * np.dot(w, x * phi),
        "m11": c * c * np.dot(w, phi**2),
        "k11_star": c * c * np.dot(w, phi2**2),
        "X1": c * tip,
    }


REF = _independent_mode_constants(L)


def test_independent_derivation_sanity():
    # textbook value of the first root of cos(x)cosh(x) + 1 = 0
    assert REF["beta_l"] == pytest.approx(1.8751040687119611, rel=1e-14)
    # |X(l)| = 2 for the clamped-free mode normalised to mean square 1 (classical identity)
    assert REF["X1"] == pytest.approx(-2.0, rel=1e-12)
    # X'''' = b^4 X and the boundary terms vanish => int X''^2 = b^4 int X^2 = (b l)^4 / l^3
    assert REF["k11_star"] == pytest.approx(REF["beta_l"] ** 4 / L**3, rel=1e-12)


@pytest.mark.parametrize("name", ["C1", "D1", "m11", "k11_star", "X1"])
def test_derived_constants_match_independent_derivation(name):
    d = derived_mode_constants(L)
    assert d.source == "derived"
    # both sides are quadrature to ~1e-13; 1e-11 leaves room for cancellation in C1, D1
    assert getattr(d, name) == pytest.approx(REF[name], rel=1e-11)


def test_derived_constants_other_length():
    # the closed-form scalings with l: X(l) = -2, m11 = l, k11* = (bl)^4 / l^3, C1 ~ l, D1 ~ l^2
    d = derived_mode_constants(1.7)
    ref = _independent_mode_constants(1.7)
    for name in ("C1", "D1", "m11", "k11_star", "X1"):
        assert getattr(d, name) == pytest.approx(ref[name], rel=1e-11)
    assert d.C1 == pytest.approx(REF["C1"] * 1.7 / L, rel=1e-11)
    assert d.D1 == pytest.approx(REF["D1"] * (1.7 / L) ** 2, rel=1e-11)


def test_paper_constants_are_the_printed_ones():
    assert mode_constants("paper", L) is PAPER_MODE_CONSTANTS
    for name, value in PRINTED.items():
        assert getattr(PAPER_MODE_CONSTANTS, name) == value


@pytest.mark.parametrize("name", ["C1", "D1", "m11", "k11_star", "X1"])
def test_printed_constants_are_a_rounding_of_the_derived_ones(name):
    # The largest disagreement is X1 (-1.9987 vs -2, 6.5e-4); all are below 1e-3.
    assert abs(PRINTED[name] / REF[name] - 1.0) <= 1e-3


def test_printed_constants_are_a_rescaling_of_the_derived_ones():
    """The printed C1, D1 are the derived ones times s, m11 and k11* times s^2.

    s^2 = 0.899850 / 0.9 (m11 is printed to 6 decimals, so s is known to
    ~1e-6).  C1 and D1 are linear in the mode amplitude, m11 and k11* are
    quadratic: the printed set is the derived set for a mode normalised to
    int X^2 = s^2 l instead of l, rounded to 6 decimals (relative rounding
    <= 5e-7 / 0.46 ~ 1e-6).  1e-5 is ten times that.
    """
    ratio = {k: PRINTED[k] / REF[k] for k in ("C1", "D1", "m11", "k11_star")}
    s = math.sqrt(ratio["m11"])
    assert s == pytest.approx(0.999915, abs=5e-6)
    assert ratio["C1"] == pytest.approx(s, rel=1e-5)
    assert ratio["D1"] == pytest.approx(s, rel=1e-5)
    assert ratio["k11_star"] == pytest.approx(s * s, rel=1e-5)
    # X1 does not follow the scaling (it would print as -1.99983); it only agrees to 6.5e-4
    assert abs(PRINTED["X1"] / REF["X1"] - s) > 1e-4


def test_unknown_constants_rejected():
    with pytest.raises(ValueError, match="constants"):
        mode_constants("printed", L)
    with pytest.raises(ValueError, match="constants"):
        ReducedModel(2 * math.pi, constants="printed")


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_derived_constants_reject_bad_length(bad):
    with pytest.raises(ValueError, match="length"):
        derived_mode_constants(bad)


# --------------------------------------------------------------------------- Eqs. 21-24 by hand
def _hand_matrices(omega: float, t: float, c: dict[str, float], kp: float = 0.0, kd: float = 0.0):
    """M_L, C_L + K_D, K_L + K_P of Eqs. (21)-(23), (32) for Table 1 data."""
    l, A, rho, mE, J1, alpha, g = 0.9, 4e-4, 2700.0, 0.1, 5.86e-5, 0.01, 9.81
    EI = 7.11e10 * 1.3333e-8
    mu = rho * A
    mOE = mu * l
    q = 0.5 * math.pi + 0.5 * math.pi * math.sin(omega * t)
    qd = 0.5 * math.pi * omega * math.cos(omega * t)
    M = np.array(
        [
            [J1 + mE * l**2 + mOE * l**2 / 3.0, mu * c["D1"] + mE * l * c["X1"]],
            [mE * l * c["X1"] + mu * c["D1"], mE * c["X1"] ** 2 + mu * c["m11"]],
        ]
    )
    C = np.array([[alpha + kd, 0.0], [0.0, 0.0]])
    k11 = -l * math.sin(q) * mE * g - mOE * g * l * math.sin(q) / 2.0
    k12 = -mE * g * c["X1"] * math.sin(q) - mu * g * math.sin(q) * c["C1"]
    k22 = -mE * qd**2 * c["X1"] ** 2 - mu * qd**2 * c["m11"] + EI * c["k11_star"]
    K = np.array([[k11 + kp, k12], [k12, k22]])
    return M, C, K


def _hand_P(M, C, K):
    Minv = np.linalg.inv(M)
    return np.block([[np.zeros((2, 2)), np.eye(2)], [-Minv @ K, -Minv @ C]])


OMEGA = 4 * math.pi
T = 2 * math.pi / OMEGA


def test_mass_matrix_eq21_symmetric_positive_definite():
    for constants, c in (("paper", PRINTED), ("derived", REF)):
        model = ReducedModel(OMEGA, constants=constants)
        M = model.mass(0.3)
        hand = _hand_matrices(OMEGA, 0.3, c)[0]
        np.testing.assert_allclose(M, hand, rtol=1e-12)
        np.testing.assert_array_equal(M, M.T)
        assert np.all(np.linalg.eigvalsh(M) > 0)
        # M_L is constant in time
        np.testing.assert_array_equal(model.mass(np.array([0.0, 0.17, 0.4])), np.stack([M] * 3))


def test_mass_matrix_printed_numbers():
    # Eq. 21 with Table 1 and the printed constants, by hand:
    # m11 = 5.86e-5 + 0.1*0.81 + 0.972*0.81/3           = 0.3434986
    # m12 = 1.08*(-0.46071) + 0.1*0.9*(-1.9987)          = -0.4975668 - 0.179883 = -0.6774498
    # m22 = 0.1*1.9987**2 + 1.08*0.89985                 = 0.399480169 + 0.971838 = 1.371318169
    M = ReducedModel(OMEGA).mass(0.0)
    np.testing.assert_allclose(
        M, [[0.3434986, -0.6774498], [-0.6774498, 1.371318169]], rtol=1e-12
    )


def test_stiffness_at_sin_q_equal_one():
    """t = 0: q = pi/2 (sin q = 1, cos q = 0), dq/dt = pi Omega / 2."""
    mE, l, g, mu = 0.1, 0.9, 9.81, 1.08
    c = PRINTED
    qd = 0.5 * math.pi * OMEGA
    K = ReducedModel(OMEGA).stiffness(0.0)
    expected = np.array(
        [
            [-l * mE * g - mu * l * g * l / 2.0, -mE * g * c["X1"] - mu * g * c["C1"]],
            [-mE * g * c["X1"] - mu * g * c["C1"],
             -(mE * c["X1"] ** 2 + mu * c["m11"]) * qd**2 + 7.11e10 * 1.3333e-8 * c["k11_star"]],
        ]
    )
    np.testing.assert_allclose(K, expected, rtol=1e-13)


def test_stiffness_at_rest_points():
    """t = T/4 (q = pi) and 3T/4 (q = 0): sin q = 0 and dq/dt = 0, so only EI k11* remains."""
    model = ReducedModel(OMEGA)
    EIk = 7.11e10 * 1.3333e-8 * 16.955151
    for t in (T / 4, 3 * T / 4):
        K = model.stiffness(t)
        # sin(q) is ~1e-16 there (q = pi to rounding), scaled by ~5 N m
        np.testing.assert_allclose(K, [[0.0, 0.0], [0.0, EIk]], rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("constants, c", [("paper", PRINTED), ("derived", REF)])
def test_matrices_and_P_at_arbitrary_times(constants, c):
    model = ReducedModel(OMEGA, 3.5, 0.7, constants=constants)
    times = np.array([0.0, 0.0123, 0.1, 0.2345, 0.4, T])
    Ps = model.evaluate(times)
    Ks = model.stiffness(times)
    Cs = model.damping(times)
    for i, t in enumerate(times):
        M, C, K = _hand_matrices(OMEGA, float(t), c, kp=3.5, kd=0.7)
        # K_L entries reach 1.6e4 and partly cancel (k22 at large qd): 1e-12 relative to the norm
        np.testing.assert_allclose(Ks[i], K, rtol=1e-12, atol=1e-12 * np.abs(K).max())
        np.testing.assert_allclose(Cs[i], C, rtol=1e-15)
        P = _hand_P(M, C, K)
        # both sides solve with M (cond 240): <= 2 n cond(M) eps = 2e-13 relative to max|P|; 1e-10 is 500x
        np.testing.assert_allclose(Ps[i], P, rtol=1e-10, atol=1e-10 * np.abs(P).max())
        np.testing.assert_allclose(model(float(t)), P, rtol=1e-10, atol=1e-10 * np.abs(P).max())
    # T-periodic: sin(Omega T) = sin(fl(2 pi)) = -2.4e-16 moves q by <= 2 ulp at pi/2, where sin q is
    # flat and cos(Omega T) = 1: equal to rounding (atol 1e-9 is ~1e-15 of max|P|)
    np.testing.assert_allclose(Ps[-1], Ps[0], rtol=1e-12, atol=1e-9)


def test_pd_gains_enter_as_eq32():
    """K_P adds to K[0, 0], K_D to C[0, 0]; M unchanged; P changes by -M^-1 diag(.., 0)."""
    base = ReducedModel(OMEGA)
    kp, kd = 23.0147, 6.8628
    ctrl = ReducedModel(OMEGA, kp, kd)
    t = np.linspace(0.0, T, 7)
    dK = ctrl.stiffness(t) - base.stiffness(t)
    dC = ctrl.damping(t) - base.damping(t)
    eK = np.zeros((2, 2))
    eK[0, 0] = kp
    eC = np.zeros((2, 2))
    eC[0, 0] = kd
    # (k + kp) - k rounds to <= eps (|k| + kp) ~ 1e-14 (the other entries are bitwise equal);
    # (alpha + kd) - alpha: two roundings at 6.87, <= ulp(6.87) = 8.9e-16
    np.testing.assert_allclose(dK, np.broadcast_to(eK, dK.shape), atol=1e-11)
    np.testing.assert_allclose(dC, np.broadcast_to(eC, dC.shape), atol=1e-15)
    np.testing.assert_array_equal(ctrl.mass(t), base.mass(t))
    Minv = np.linalg.inv(_hand_matrices(OMEGA, 0.0, PRINTED)[0])
    dP = ctrl.evaluate(t) - base.evaluate(t)
    expected = np.zeros((4, 4))
    expected[2:, 0:2] = -Minv @ eK
    expected[2:, 2:] = -Minv @ eC
    # the gains change column 0 of K and C only; M^-1 (cond 240) times them: <= n cond(M) eps ~ 1e-13
    # relative to |M^-1 kp| ~ 2.6e3; the untouched columns of P are bitwise equal (same inputs)
    np.testing.assert_allclose(dP, np.broadcast_to(expected, dP.shape), rtol=1e-9, atol=1e-9)
    # with_gains is the same model
    np.testing.assert_array_equal(base.with_gains(kp, kd).evaluate(t), ctrl.evaluate(t))


def test_trace_integral_closed_form():
    # tr P = -tr(M^-1 C) = -(alpha + kd) (M^-1)_11 = -(alpha + kd) m22 / det M
    M = _hand_matrices(OMEGA, 0.0, PRINTED)[0]
    for kd in (0.0, 6.8628):
        expected = -T * (0.01 + kd) * M[1, 1] / np.linalg.det(M)
        assert ReducedModel(OMEGA, 0.0, kd).trace_integral() == pytest.approx(expected, rel=1e-12)


def test_period_and_fundamental_motion():
    model = ReducedModel(OMEGA)
    assert model.period == pytest.approx(0.5, rel=1e-15)
    m = model.motion
    assert float(m.angle(0.0)) == pytest.approx(math.pi / 2)
    assert float(m.angle(T / 4)) == pytest.approx(math.pi)
    assert float(m.velocity(0.0)) == pytest.approx(math.pi / 2 * OMEGA)
    assert float(m.acceleration(T / 4)) == pytest.approx(-math.pi / 2 * OMEGA**2)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"omega": 0.0}, "omega"),
        ({"omega": -2.0}, "omega"),
        ({"omega": math.nan}, "omega"),
        ({"omega": math.inf}, "omega"),
        ({"omega": "2pi"}, "omega"),
        ({"kp": -1.0}, "kp"),
        ({"kp": math.nan}, "kp"),
        ({"kd": -0.1}, "kd"),
        ({"kd": math.inf}, "kd"),
        ({"kd": None}, "kd"),
    ],
)
def test_bad_input_names_the_field(kwargs, name):
    args = {"omega": 2 * math.pi, **kwargs}
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        ReducedModel(**args)


def test_bad_params_object():
    with pytest.raises(ValueError, match="params"):
        ReducedModel(2 * math.pi, params={"length": 0.9})  # type: ignore[arg-type]
