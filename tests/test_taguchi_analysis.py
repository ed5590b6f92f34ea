"""Response table, ANOVA contributions and prediction on responses with a known answer.

Oracle 1: a synthetic additive S/N, ``eta = 10 + a_i + b_j (+ c_k)`` on an
orthogonal array, with zero-sum effects.  Then (Phadke 1989, Ch. 3) the level
means are exactly ``10 + a_i`` and ``10 + b_j``, the factor sums of squares
are ``(N/s) sum a_i^2`` and ``(N/s) sum b_j^2``, an unassigned column's effect
``c_k`` is the error, and the additive prediction is exact.  The expected
numbers are worked by hand in each test.

Oracle 2: for any S/N on an orthogonal array, the factor sums of squares equal
the drop in residual sum of squares of a least-squares fit with dummy-coded
factors (Montgomery 2013, Ch. 12 / general linear model), computed here with
``numpy.linalg.lstsq``.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from taguchi.analysis import (
    AnovaTable,
    ResponseTable,
    TaguchiAnalysis,
    analyze,
    anova,
    best_levels,
    predict_sn,
    response_table,
)
from taguchi.arrays import get_array

# zero-sum effects (dB)
A = (1.5, -0.5, -1.0)
B = (-0.3, 0.1, 0.2)
C = (0.05, -0.15, 0.10)


def _synthetic(oa_matrix, effects, mean=10.0):
    return np.array([mean + sum(e[row[j]] for j, e in enumerate(effects)) for row in oa_matrix])


def test_response_table_recovers_known_effects_on_l9():
    oa = get_array("L9")
    sn = _synthetic(oa.matrix, [A, B])
    t = response_table(oa, sn, ["kp", "kd"])
    assert isinstance(t, ResponseTable)
    # level means = 10 + a_i, 10 + b_j
    np.testing.assert_allclose(t.level_means[0], [11.5, 9.5, 9.0], atol=1e-12)
    np.testing.assert_allclose(t.level_means[1], [9.7, 10.1, 10.2], atol=1e-12)
    # delta_A = 1.5 - (-1.0) = 2.5, delta_B = 0.2 - (-0.3) = 0.5; rank by delta
    assert t.delta == pytest.approx((2.5, 0.5), abs=1e-12)
    assert t.rank == (1, 2)
    assert t.overall_mean == pytest.approx(10.0, abs=1e-12)
    assert t.factors == ("kp", "kd") and t.columns == (0, 1) and t.levels == (3, 3)
    assert t.sn == tuple(sn)
    assert best_levels(t) == (0, 2)


def test_contributions_equal_known_sum_of_squares_ratios():
    oa = get_array("L9")
    sn = _synthetic(oa.matrix, [A, B])
    aov = anova(oa, sn, ["kp", "kd"])
    assert isinstance(aov, AnovaTable)
    # SS_A = 3 * (1.5^2 + 0.5^2 + 1.0^2) = 3 * 3.5 = 10.5
    # SS_B = 3 * (0.09 + 0.01 + 0.04) = 3 * 0.14 = 0.42
    # SS_T = 10.92 (additive, orthogonal: no error); P_A = 10.5/10.92, P_B = 0.42/10.92
    assert aov.sum_of_squares == pytest.approx((10.5, 0.42), rel=1e-12)
    assert aov.total_sum_of_squares == pytest.approx(10.92, rel=1e-12)
    assert aov.contribution_percent == pytest.approx((100 * 10.5 / 10.92, 100 * 0.42 / 10.92), rel=1e-12)
    assert aov.contribution_percent[0] == pytest.approx(96.153846, abs=1e-6)
    assert aov.error_sum_of_squares == 0.0
    assert aov.error_contribution_percent == 0.0
    assert aov.dof == (2, 2) and aov.error_dof == 4 and aov.total_dof == 8
    assert aov.mean_square == pytest.approx((5.25, 0.21), rel=1e-12)
    assert all(np.isnan(aov.f_ratio))  # zero error mean square: F undefined


def test_unassigned_column_effect_is_the_error_term():
    oa = get_array("L9")
    sn = _synthetic(oa.matrix, [A, B, C])  # C sits in column 2, not analysed
    aov = anova(oa, sn, ["kp", "kd"])
    # SS_C = 3 * (0.0025 + 0.0225 + 0.01) = 3 * 0.035 = 0.105
    ss_t = 10.5 + 0.42 + 0.105
    assert aov.error_sum_of_squares == pytest.approx(0.105, rel=1e-10)
    assert aov.total_sum_of_squares == pytest.approx(ss_t, rel=1e-12)
    assert aov.contribution_percent == pytest.approx((100 * 10.5 / ss_t, 100 * 0.42 / ss_t), rel=1e-10)
    assert aov.error_contribution_percent == pytest.approx(100 * 0.105 / ss_t, rel=1e-10)
    assert sum(aov.contribution_percent) + aov.error_contribution_percent == pytest.approx(100.0)
    # MS_e = 0.105 / 4; F_A = (10.5/2) / (0.105/4) = 200, F_B = (0.42/2)/(0.105/4) = 8
    assert aov.error_mean_square == pytest.approx(0.105 / 4, rel=1e-10)
    assert aov.f_ratio == pytest.approx((200.0, 8.0), rel=1e-9)
    # the response table still recovers a_i and b_j (orthogonality)
    t = response_table(oa, sn, ["kp", "kd"])
    np.testing.assert_allclose(t.level_means[0], [11.5, 9.5, 9.0], atol=1e-12)


def test_factor_columns_can_be_chosen():
    oa = get_array("L9")
    sn = _synthetic(oa.matrix, [A, B, C])
    t = response_table(oa, sn, ["C", "A"], columns=[2, 0])
    np.testing.assert_allclose(t.level_means[0], [10.05, 9.85, 10.10], atol=1e-12)
    np.testing.assert_allclose(t.level_means[1], [11.5, 9.5, 9.0], atol=1e-12)
    assert t.rank == (2, 1)


def test_prediction_is_exact_for_an_additive_response():
    oa = get_array("L9")
    sn = _synthetic(oa.matrix, [A, B])
    t = response_table(oa, sn)
    assert t.factors == ("A", "B", "C", "D")
    t2 = response_table(oa, sn, ["kp", "kd"])
    for i, j in itertools.product(range(3), repeat=2):
        # additive model: 10 + a_i + b_j
        assert predict_sn(t2, (i, j)) == pytest.approx(10 + A[i] + B[j], abs=1e-12)
        assert predict_sn(t2, {"kd": j, "kp": i}) == pytest.approx(10 + A[i] + B[j], abs=1e-12)
    # default levels = best levels: a_0 = 1.5, b_2 = 0.2 -> 10 + 1.5 + 0.2 = 11.7 dB
    assert predict_sn(t2) == pytest.approx(11.7, abs=1e-12)


def test_l25_five_levels_known_answer():
    oa = get_array("L25")
    a = (2.0, 1.0, 0.0, -1.0, -2.0)
    b = (0.0, 0.5, -0.5, 0.25, -0.25)
    sn = _synthetic(oa.matrix, [a, b], mean=-5.0)
    res = analyze(oa, sn, ["kp", "kd"])
    assert isinstance(res, TaguchiAnalysis)
    np.testing.assert_allclose(res.response_table.level_means[0], np.add(a, -5.0), atol=1e-12)
    np.testing.assert_allclose(res.response_table.level_means[1], np.add(b, -5.0), atol=1e-12)
    # SS_a = 5 * 10 = 50, SS_b = 5 * 0.625 = 3.125
    assert res.anova.sum_of_squares == pytest.approx((50.0, 3.125), rel=1e-12)
    assert res.anova.contribution_percent == pytest.approx((100 * 50 / 53.125, 100 * 3.125 / 53.125))
    assert res.best_levels == (0, 1)
    assert res.predicted_sn == pytest.approx(-5.0 + 2.0 + 0.5, abs=1e-12)


def _rss(X, y):
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    return float(r @ r)


def _dummies(col, s):
    return np.column_stack([(col == k).astype(float) for k in range(1, s)])


@pytest.mark.filterwarnings("ignore:all S/N ratios are equal:RuntimeWarning")
@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-50, 50, allow_nan=False), min_size=9, max_size=9))
def test_sums_of_squares_match_least_squares_oracle(values):
    oa = get_array("L9")
    y = np.array(values)
    aov = anova(oa, y, ["A", "B"])
    ones = np.ones((9, 1))
    da, db = _dummies(oa.matrix[:, 0], 3), _dummies(oa.matrix[:, 1], 3)
    rss_0 = _rss(ones, y)
    rss_full = _rss(np.hstack([ones, da, db]), y)
    ss_a = _rss(np.hstack([ones, db]), y) - rss_full
    ss_b = _rss(np.hstack([ones, da]), y) - rss_full
    scale = max(rss_0, 1.0)
    assert aov.total_sum_of_squares == pytest.approx(rss_0, abs=1e-9 * scale)
    assert aov.sum_of_squares[0] == pytest.approx(ss_a, abs=1e-9 * scale)
    assert aov.sum_of_squares[1] == pytest.approx(ss_b, abs=1e-9 * scale)
    assert aov.error_sum_of_squares == pytest.approx(rss_full, abs=1e-9 * scale)


def test_rank_ties_follow_factor_order_and_best_level_ties_go_low():
    oa = get_array("L9")
    sn = _synthetic(oa.matrix, [(1.0, 0.0, -1.0), (-1.0, 0.0, 1.0)])
    t = response_table(oa, sn)
    assert t.rank[:2] == (1, 2)
    flat = response_table(oa, _synthetic(oa.matrix, [(1.0, 1.0, -2.0), B]), ["A", "B"])
    assert best_levels(flat)[0] == 0


def test_results_are_frozen_and_serialisable():
    oa = get_array("L9")
    res = analyze(oa, _synthetic(oa.matrix, [A, B]), ["kp", "kd"])
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.predicted_sn = 0.0  # type: ignore[misc]
    d = res.to_dict()
    assert d["response_table"]["factors"] == ("kp", "kd")
    text = res.response_table.format()
    assert "Delta" in text and "Rank" in text and "11.500" in text


def test_plain_matrix_input_works():
    full = np.array(list(itertools.product(range(3), repeat=2)))  # 3^2 full factorial
    sn = _synthetic(full, [A, B])
    t = response_table(full, sn)
    np.testing.assert_allclose(t.level_means[0], [11.5, 9.5, 9.0], atol=1e-12)


def test_constant_sn_warns_and_gives_nan_contributions():
    oa = get_array("L9")
    with pytest.warns(RuntimeWarning, match="equal"):
        aov = anova(oa, np.full(9, 3.0), ["A", "B"])
    assert all(np.isnan(aov.contribution_percent))


@pytest.mark.parametrize(
    "sn, kwargs, match",
    [
        ([], {}, "non-empty"),
        ([1.0] * 8, {}, "9 runs"),
        ([1.0] * 8 + [np.nan], {}, "finite"),
        ([1.0] * 8 + [np.inf], {}, "finite"),
        ([1.0] * 9, {"factor_names": ["A", "A"]}, "distinct"),
        ([1.0] * 9, {"factor_names": ["A"], "columns": [0, 1]}, "names"),
        ([1.0] * 9, {"columns": [0, 4]}, "columns"),
    ],
)
def test_bad_input(sn, kwargs, match):
    with pytest.raises(ValueError, match=match):
        response_table(get_array("L9"), sn, **kwargs)


def test_non_orthogonal_design_rejected():
    full = np.array(list(itertools.product(range(3), repeat=2)))
    dup = np.column_stack([full[:, 0], full[:, 0]])
    with pytest.raises(ValueError, match="orthogonal"):
        response_table(dup, np.arange(9.0))


def test_predict_rejects_bad_levels():
    oa = get_array("L9")
    t = response_table(oa, _synthetic(oa.matrix, [A, B]), ["kp", "kd"])
    for bad in [(0,), (0, 3), (0, -1), (0, 1.0), {"kp": 0}, {"kp": 0, "kd": 1, "x": 2}]:
        with pytest.raises(ValueError):
            predict_sn(t, bad)
