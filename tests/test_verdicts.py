"""The verdict rule (stability.verdict) against analytic multipliers.

Oracles: constant ``P`` (multipliers ``exp(lambda T)`` in closed form) and the damped Mathieu
equation ``x'' + 2 c x' + (a - 2 q cos 2t) x = 0`` in a stable band, where Liouville's
formula fixes both moduli: ``rho1 rho2 = exp(-2 c pi)`` and the pair is complex conjugate, so
``|rho1| = |rho2| = exp(-c pi)`` exactly (the band edges from ``scipy.special.mathieu_a`` / ``mathieu_b``).
Each test also shows the rule rejecting the wrong verdict (the former rule, ``rho < 1 - tol``,
called the decays of 4e5 periods of an undamped mesh asymptotically stable).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import mathieu_a, mathieu_b

from stability import floquet
from stability.verdict import (DECAY_PERIODS, VERDICT_CRITICAL, VERDICT_STABLE, VERDICT_UNSTABLE, judge,
                               judge_floquet, threshold, verdict_band)


def test_threshold_is_decay_by_e_within_n_periods():
    r = threshold()
    assert r ** DECAY_PERIODS == pytest.approx(math.exp(-1.0), rel=1e-12)
    assert threshold(10.0) == pytest.approx(math.exp(-0.1), rel=1e-15)
    with pytest.raises(ValueError):
        threshold(0.0)


def test_mesh_like_spectral_radius_is_critical_not_stable():
    # the 8-element single link at 2 pi, Table 3 gains: 0.9999977 with error ~1e-10 -- decays by e
    # in 4.3e5 periods: critical (the former rule rho < 1 - 1e-8 said asymptotically stable)
    v = judge([0.9999977, 0.9999977, 0.3, 0.3], [1e-10] * 4, labels=["axial 13", "axial 13", "hub", "hub"])
    assert v.verdict == VERDICT_CRITICAL
    assert v.undamped_labels == ("axial 13",) and len(v.undamped) == 2
    assert v.spectral_radius_label == "axial 13"
    assert v.periods_to_decay == pytest.approx(-1.0 / math.log(0.9999977), rel=1e-12)
    assert "2 of 4" in v.message and "axial 13" in v.message
    assert v.margin < 0


def test_error_bar_decides_between_stable_and_critical():
    r = threshold()
    below = r - 1e-6
    assert judge([below], [1e-7]).verdict == VERDICT_STABLE
    assert judge([below], [2e-6]).verdict == VERDICT_CRITICAL  # not certified below the threshold
    assert judge([below], [math.nan]).verdict == VERDICT_CRITICAL  # unknown error: never certified
    v = judge([below], [1e-7])
    assert v.margin == pytest.approx(1e-6 - 1e-7, rel=1e-6)


def test_unstable_needs_certified_growth():
    assert judge([1.01, 0.5], [1e-3, 1e-9], labels=["axial 6", "hub"]).verdict == VERDICT_UNSTABLE
    v = judge([1.01, 0.5], [1e-3, 1e-9], labels=["axial 6", "hub"])
    assert v.growing_labels == ("axial 6",) and not v.undamped
    # 1.0022 with an error of 3.9e-3 (the hub-frame product at 8 pi): not certified growing -> critical
    assert judge([1.0022], [3.9e-3]).verdict == VERDICT_CRITICAL


def test_bad_inputs_rejected():
    with pytest.raises(ValueError):
        judge([], [])
    with pytest.raises(ValueError):
        judge([0.5, 0.4], [1e-9])
    with pytest.raises(ValueError):
        judge([math.nan], [1e-9])
    with pytest.raises(ValueError):
        judge([0.5], [1e-9], labels=["a", "b"])


def _constant(decay_periods: float, T: float = 2.0):
    """``P`` constant: an oscillator pair with ``Re lambda T = -1 / decay_periods`` and a fast decaying one."""
    s = -1.0 / (decay_periods * T)
    A = np.array([[s, 3.0, 0.0], [-3.0, s, 0.0], [0.0, 0.0, -2.0]])
    return A, T


@pytest.mark.parametrize("periods, expected", [(300.0, VERDICT_STABLE), (900.0, VERDICT_STABLE),
                                               (1100.0, VERDICT_CRITICAL), (1e5, VERDICT_CRITICAL)])
def test_floquet_verdict_on_constant_P(periods, expected):
    A, T = _constant(periods)
    res = floquet(lambda t: A, period=T)
    # analytic moduli exp(Re lambda T)
    np.testing.assert_allclose(np.sort(res.moduli)[::-1], [math.exp(-1 / periods)] * 2 + [math.exp(-2 * T)],
                               rtol=1e-10)
    assert res.verdict == expected
    v = judge_floquet(res, labels=["pair", "pair", "fast"])
    assert v.verdict == expected == verdict_band(res.spectral_radius, res.stability_tolerance)
    if expected == VERDICT_CRITICAL:
        assert v.undamped_labels == ("pair",) and len(v.undamped) == 2
    else:
        assert v.periods_to_decay == pytest.approx(periods, rel=1e-8)
        assert v.margin > 0 and "decays by e in" in v.message


def _damped_mathieu(a: float, q: float, c: float):
    def P(t):
        return np.array([[0.0, 1.0], [-(a - 2.0 * q * math.cos(2.0 * t)), -2.0 * c]])
    return P


@pytest.mark.parametrize("periods, expected", [(400.0, VERDICT_STABLE), (4000.0, VERDICT_CRITICAL)])
def test_damped_mathieu_in_stable_band(periods, expected):
    q = 1.0
    # the first stable band a0 < a < b1 (x = exp(-c t) y turns the equation into undamped Mathieu with a - c^2)
    a = 0.5 * (float(mathieu_a(0, q)) + float(mathieu_b(1, q)))
    c = 1.0 / (periods * math.pi)  # |rho| = exp(-c pi) = exp(-1 / periods)
    res = floquet(_damped_mathieu(a, q, c), period=math.pi)
    np.testing.assert_allclose(res.moduli, math.exp(-1.0 / periods), rtol=1e-9)
    v = judge_floquet(res)
    assert v.verdict == expected == res.verdict
    # the wrong answer of the former rule (stable whenever rho < 1 - tol) is rejected here
    if expected == VERDICT_CRITICAL:
        assert res.spectral_radius < 1.0 - 1e-6 and v.verdict != VERDICT_STABLE


def test_verdict_band_is_judge_on_one_modulus():
    """The short rule for the spectral radius gives the verdict of the full rule on every edge: the
    threshold and 1 approached from both sides, zero / inf / NaN / negative bands, rho at 0 and inf."""
    r_star = threshold()
    rhos = [0.0, 0.5, r_star - 1e-9, r_star, r_star + 1e-9, 1.0 - 1e-12, 1.0, 1.0 + 1e-12, 2.0, math.inf]
    tols = [0.0, 1e-12, 1e-9, 1e-3, 0.5, 2.0, math.inf, math.nan, -1.0]
    for rho in rhos:
        for tol in tols:
            for periods in (10.0, DECAY_PERIODS):
                expected = judge([rho], [tol], decay_periods=periods, stability_tol=0.0).verdict
                assert verdict_band(rho, tol, periods) == expected, (rho, tol, periods)
    with pytest.raises(ValueError):
        verdict_band(math.nan, 0.0)
    with pytest.raises(ValueError):
        verdict_band(-1.0, 0.0)


@pytest.mark.parametrize("err", [0.0, 1.0, math.inf, math.nan])
def test_infinite_modulus_is_unstable_whatever_its_error(err):
    """An overflowed multiplier (|rho| = inf) grows; with an unknown or infinite error the old
    comparisons gave NaN lower bounds and judged it stable."""
    v = judge([math.inf, 0.1], [err, 1e-9], stability_tol=0.0)
    assert v.verdict == VERDICT_UNSTABLE and v.growing == (0,)
    assert verdict_band(math.inf, err) == VERDICT_UNSTABLE


def test_unknown_error_is_never_certified_damped():
    """A modulus inside the unit circle with an unknown (inf / NaN) error is critical: neither
    certified damped nor certified growing."""
    for err in (math.inf, math.nan):
        assert judge([0.2], [err]).verdict == VERDICT_CRITICAL
        assert verdict_band(0.2, err) == VERDICT_CRITICAL
    assert judge([0.2], [1e-9]).verdict == VERDICT_STABLE
