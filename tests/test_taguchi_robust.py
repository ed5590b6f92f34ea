"""Robust design (crossed inner x outer arrays), model-free (issue 11).

Oracle: an objective whose robust optimum is known in closed form,

    y(g, z) = rho_d + a z1 (g1 - c1) + a z2 (g2 - c2) + b (g1 + g2 - c1 - c2)^2,

with noise z1, z2 in [-1, 1].  Over a balanced outer array (E z = 0, E z1 z2 = 0)
the mean quadratic loss about rho_d is a^2 E[z^2] ((g1 - c1)^2 + (g2 - c2)^2) +
b^2 (g1 + g2 - c1 - c2)^4, zero only at (c1, c2): the robust optimum.  At the
nominal noise z = 0 every point of the line g1 + g2 = c1 + c2 reaches rho_d, and
the worst case over the noise box is rho_d + a (|g1 - c1| + |g2 - c2|) + b (...)^2.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from taguchi.robust import NoiseFactor, RobustConfig, noise_grid, robust_tune, worst_case
from taguchi.tuning import TuningConfig, taguchi_tune

RHO_D, A, B, C1, C2 = 0.3, 0.04, 0.05, 1.3, 2.6
RANGES = ((0.0, 4.0), (0.0, 4.0))
NOISE = (NoiseFactor("z1", -1.0, 1.0, 0.0), NoiseFactor("z2", -1.0, 1.0, 0.0))


def objective(g, n):
    # a (|g1 - c1| + |g2 - c2|) <= 0.04 * 5.3 < rho_d: y stays positive on the box
    return RHO_D + A * n["z1"] * (g[0] - C1) + A * n["z2"] * (g[1] - C2) + B * (g[0] + g[1] - C1 - C2) ** 2


def analytic_worst(g):
    return RHO_D + A * (abs(g[0] - C1) + abs(g[1] - C2)) + B * (g[0] + g[1] - C1 - C2) ** 2


def test_robust_optimum_known_analytically():
    cfg = RobustConfig(tuning=TuningConfig(ranges=RANGES, max_evaluations=5000), noise=NOISE)
    res = robust_tune(objective, cfg)
    assert res.status == "converged"
    assert res.outer_array.startswith("L9") and len(res.outer_runs) == 9
    # the final ranges are <= xtol W wide, centred on the incumbent; the optimum lies within the
    # previous range, whose levels are (2 xtol W) / 2 apart: |g - c| <= 2 xtol W
    bound = 2 * cfg.xtol * 4.0
    assert abs(res.gains[0] - C1) <= bound and abs(res.gains[1] - C2) <= bound
    assert res.evaluations == sum((9 + 1) * 9 for _ in res.iterations)
    # the recorded S/N is the loss over the outer runs, recomputed here
    ys = [objective(res.gains, o) for o in res.outer_runs]
    assert res.sn == pytest.approx(-10 * math.log10(np.mean((np.array(ys) - RHO_D) ** 2)), rel=1e-12)


def test_worst_case_grid_prefers_robust_over_nominal_gains():
    cfg = RobustConfig(tuning=TuningConfig(ranges=RANGES, max_evaluations=5000), noise=NOISE)
    robust = robust_tune(objective, cfg)
    nominal = taguchi_tune(lambda g: objective(g, cfg.nominal_noise), TuningConfig(ranges=RANGES))
    grid = noise_grid(NOISE, 21)  # 441 points, not the outer array
    assert len(grid) == 441
    wr = worst_case(objective, robust.gains, grid, cfg.nominal_noise)
    wn = worst_case(objective, nominal.gains, grid, cfg.nominal_noise)
    # y is affine in z: the worst case sits on a corner of the box, which the grid contains
    assert wr.worst == pytest.approx(analytic_worst(robust.gains), rel=1e-12)
    assert wn.worst == pytest.approx(analytic_worst(nominal.gains), rel=1e-12)
    assert wr.worst < wn.worst
    # the nominal tuning is right at nominal noise but not robust: a wrong "robust" answer
    assert abs(wn.nominal - RHO_D) <= 1e-3 * RHO_D
    assert wn.worst - RHO_D > 10 * (wr.worst - RHO_D)


def test_smaller_the_better_pushes_to_the_range_edge():
    # y = 0.1 + 1/(1 + g): smaller-the-better is maximised at the upper end of the range
    cfg = RobustConfig(tuning=TuningConfig(ranges=((0.0, 10.0), (0.0, 10.0)), max_evaluations=5000),
                       noise=(NoiseFactor("m", 0.5, 1.5, 1.0),), sn="smaller")
    res = robust_tune(lambda g, n: 0.1 + n["m"] / (1.0 + g[0] + g[1]), cfg)
    assert res.gains[0] == pytest.approx(10.0) and res.gains[1] == pytest.approx(10.0)


@pytest.mark.parametrize("kwargs, word", [
    ({"noise": ()}, "noise"),
    ({"noise": (NoiseFactor("a", 0, 1, 0.5), NoiseFactor("a", 0, 1, 0.5))}, "distinct"),
    ({"noise": NOISE, "sn": "larger"}, "S/N"),
    ({"noise": NOISE, "xtol": 0.0}, "xtol"),
])
def test_bad_robust_config(kwargs, word):
    with pytest.raises(ValueError, match=word):
        RobustConfig(**kwargs)


@pytest.mark.parametrize("args, word", [
    (("m", 1.0, 0.5, 0.7), "inverted"),
    (("m", 0.0, 1.0, 2.0), "nominal"),
    (("m", 0.0, float("nan"), 0.5), "finite"),
])
def test_bad_noise_factor(args, word):
    with pytest.raises(ValueError, match=word):
        NoiseFactor(*args)


def test_budget_smaller_than_one_crossed_experiment():
    cfg = RobustConfig(tuning=TuningConfig(ranges=RANGES, max_evaluations=50), noise=NOISE)
    with pytest.raises(ValueError, match="crossed experiment"):
        robust_tune(objective, cfg)
