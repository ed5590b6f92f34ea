"""S/N ratios against worked examples computed by hand from the textbook formulas.

Formulas (Phadke 1989, *Quality Engineering Using Robust Design*, Ch. 5;
Ross 1996, *Taguchi Techniques for Quality Engineering*, S/N chapter;
Yang & El-Haik, *Design for Six Sigma*, Eqs. 14.13-14.15 for type I with
``s^2 = sum (y - ybar)^2 / (n - 1)``):

* smaller-the-better  eta = -10 log10( (1/n) sum y^2 )
* larger-the-better   eta = -10 log10( (1/n) sum 1/y^2 )
* nominal, type I     eta =  10 log10( ybar^2 / s^2 )
* nominal, type II    eta = -10 log10( s^2 )
* target (MSD form)   eta = -10 log10( (1/n) sum (y - m)^2 )   (paper Eq. 34)

Each expected value below is worked by hand (the intermediate sums are
written out as exact fractions), then converted to dB; the decimal literal is
given too, so a mistake in either shows.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from taguchi.sn import (
    LOSS_FLOOR,
    SN_CEILING_DB,
    SN_RATIOS,
    larger_the_better,
    nominal_the_best,
    nominal_the_best_type2,
    quadratic_loss,
    smaller_the_better,
    sn_ratio,
    sn_ratios,
    sn_target,
)


def test_smaller_the_better_worked_example():
    # y = 1, 2, 3: sum y^2 = 1 + 4 + 9 = 14, MSD = 14/3 = 4.6667
    # eta = -10 log10(14/3) = -6.6901 dB
    expected = -10 * math.log10(14 / 3)
    assert expected == pytest.approx(-6.690068, abs=1e-6)
    assert smaller_the_better([1.0, 2.0, 3.0]) == pytest.approx(expected, rel=1e-12)


def test_smaller_the_better_surface_roughness_style_example():
    # y = 0.2, 0.4 (um): sum y^2 = 0.04 + 0.16 = 0.20, MSD = 0.10, eta = +10 dB exactly
    assert smaller_the_better([0.2, 0.4]) == pytest.approx(10.0, rel=1e-12)


def test_larger_the_better_worked_example():
    # y = 2, 4: sum 1/y^2 = 1/4 + 1/16 = 5/16, MSD = 5/32 = 0.15625
    # eta = -10 log10(5/32) = 8.0618 dB
    expected = -10 * math.log10(5 / 32)
    assert expected == pytest.approx(8.061800, abs=1e-6)
    assert larger_the_better([2.0, 4.0]) == pytest.approx(expected, rel=1e-12)
    # y = 10, 10, 10: MSD = 1/100, eta = 20 dB exactly
    assert larger_the_better([10.0, 10.0, 10.0]) == pytest.approx(20.0, rel=1e-12)


def test_nominal_the_best_type1_worked_example():
    # y = 9, 10, 11: ybar = 10, s^2 = (1 + 0 + 1)/(3 - 1) = 1
    # eta = 10 log10(100 / 1) = 20 dB exactly
    assert nominal_the_best([9.0, 10.0, 11.0]) == pytest.approx(20.0, rel=1e-12)
    # y = 9, 11: ybar = 10, s^2 = (1 + 1)/(2 - 1) = 2, eta = 10 log10(50) = 16.9897 dB
    expected = 10 * math.log10(100 / 2)
    assert expected == pytest.approx(16.989700, abs=1e-6)
    assert nominal_the_best([9.0, 11.0]) == pytest.approx(expected, rel=1e-12)


def test_nominal_the_best_type2_worked_example():
    # y = 9, 11: s^2 = 2, eta = -10 log10 2 = -3.0103 dB (signed responses allowed)
    assert nominal_the_best_type2([9.0, 11.0]) == pytest.approx(-10 * math.log10(2), rel=1e-12)
    assert nominal_the_best_type2([-1.0, 1.0]) == pytest.approx(-10 * math.log10(2), rel=1e-12)


def test_target_form_single_deterministic_run():
    # paper Eq. 34: y = max|rho| = 0.31, rho_d = 0.3: loss = 0.01^2 = 1e-4, eta = 40 dB
    assert sn_target(0.31, 0.3) == pytest.approx(40.0, rel=1e-9)
    # Table 3 check: 0.29999 against 0.3 -> loss 1e-10 -> 100 dB
    assert sn_target(0.29999, 0.3) == pytest.approx(100.0, rel=1e-6)
    # y = 0.5, target 0.3: loss 0.04, eta = -10 log10 0.04 = 13.9794 dB
    assert sn_target(0.5, 0.3) == pytest.approx(13.979400, abs=1e-6)


def test_target_form_replicates():
    # y = 0.29, 0.32, m = 0.3: losses 1e-4, 4e-4, mean 2.5e-4, eta = 36.0206 dB
    expected = -10 * math.log10(2.5e-4)
    assert expected == pytest.approx(36.020600, abs=1e-6)
    assert sn_target([0.29, 0.32], 0.3) == pytest.approx(expected, rel=1e-9)
    assert quadratic_loss([0.29, 0.32], 0.3) == pytest.approx(2.5e-4, rel=1e-9)


def test_target_form_on_target_is_clipped_not_infinite():
    assert SN_CEILING_DB == pytest.approx(300.0)
    assert LOSS_FLOOR == 1e-30
    assert sn_target(0.3, 0.3) == SN_CEILING_DB
    assert math.isfinite(sn_target([0.3, 0.3], 0.3))
    assert smaller_the_better([0.0, 0.0]) == SN_CEILING_DB


def test_target_zero_equals_smaller_the_better():
    y = [0.1, 0.7, 1.3]
    assert sn_target(y, 0.0) == pytest.approx(smaller_the_better(y), rel=1e-12)


@given(
    st.floats(0.01, 2.0), st.floats(1e-6, 1.0), st.floats(1e-6, 1.0)
)
def test_target_form_larger_is_closer(target, d1, d2):
    near, far = sorted([d1, d2])
    assert sn_target(target + near, target) >= sn_target(target + far, target)
    assert sn_target(target - near, target) == pytest.approx(sn_target(target + near, target), rel=1e-6)


def test_nominal_the_best_undefined_for_one_deterministic_run():
    with pytest.raises(ValueError, match="sn_target"):
        nominal_the_best(0.3)
    with pytest.raises(ValueError, match="sn_target"):
        nominal_the_best([0.3, 0.3])  # s = 0
    with pytest.raises(ValueError, match="sn_target"):
        nominal_the_best_type2([0.3])
    with pytest.raises(ValueError):
        nominal_the_best([-1.0, 1.0])  # zero mean


@pytest.mark.parametrize("fn", [smaller_the_better, larger_the_better, nominal_the_best, nominal_the_best_type2])
@pytest.mark.parametrize("bad", [[], [1.0, np.nan], [np.inf, 1.0], [[1.0, 2.0], [3.0, 4.0]]])
def test_bad_data(fn, bad):
    with pytest.raises(ValueError):
        fn(bad)


@pytest.mark.parametrize("y, target", [([], 0.3), ([np.nan], 0.3), (0.3, np.nan), (0.3, "x")])
def test_bad_target_data(y, target):
    with pytest.raises(ValueError):
        sn_target(y, target)


def test_larger_the_better_zero_is_rejected():
    with pytest.raises(ValueError, match="zero"):
        larger_the_better([0.0, 1.0])


def test_registry_and_vectorised():
    assert set(SN_RATIOS) == {"smaller", "larger", "nominal", "nominal2", "target"}
    r = sn_ratios([0.31, 0.5, 0.3], "target", target=0.3)
    np.testing.assert_allclose(r, [40.0, 13.979400, SN_CEILING_DB], atol=1e-6)
    r2 = sn_ratios([[1.0, 2.0, 3.0], [0.2, 0.4, 0.0]], "smaller")
    np.testing.assert_allclose(r2, [-10 * math.log10(14 / 3), -10 * math.log10(0.2 / 3)])
    assert sn_ratio([9.0, 10.0, 11.0], "nominal") == pytest.approx(20.0)
    with pytest.raises(ValueError, match="unknown"):
        sn_ratio(1.0, "biggest")
    with pytest.raises(ValueError, match="target"):
        sn_ratio(1.0, "target")
    with pytest.raises(ValueError, match="no target"):
        sn_ratio(1.0, "smaller", target=0.0)
    with pytest.raises(ValueError):
        sn_ratios([], "smaller")
