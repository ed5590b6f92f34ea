"""Robust design (crossed inner x outer arrays), model-free.

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


# --- failed runs: the contract of taguchi_tune, for the crossed arrays -----------------

def _failing(fail):
    """``objective`` raising ``FloquetError`` where ``fail(g, n)``."""
    from stability.floquet import FloquetError

    def obj(g, n):
        if fail(g, n):
            raise FloquetError("monodromy overflow")
        return objective(g, n)

    return obj


def test_failed_crossed_runs_are_recorded_and_the_robust_tuning_goes_on():
    """A ``FloquetError`` at g2 = 0 for the outer runs with z1 = 1 (3 inner rows x 3 outer runs of the
    first experiment) used to abort ``robust_tune``."""
    import io
    import json

    from flexstab.options import dump_json

    cfg = RobustConfig(tuning=TuningConfig(ranges=RANGES, max_evaluations=5000), noise=NOISE)
    res = robust_tune(_failing(lambda g, n: g[1] == 0.0 and n["z1"] == 1.0), cfg)
    assert res.status == "converged"
    bound = 2 * cfg.xtol * 4.0  # as in test_robust_optimum_known_analytically
    assert abs(res.gains[0] - C1) <= bound and abs(res.gains[1] - C2) <= bound
    it0 = res.iterations[0]
    bad_rows = [i for i, p in enumerate(it0.design) if p[1] == 0.0]
    bad_outer = [j for j, o in enumerate(res.outer_runs) if o["z1"] == 1.0]
    assert len(bad_rows) == 3 and len(bad_outer) == 3
    assert len(res.failed_runs) == 9 and it0.failures == res.failed_runs
    assert {(f["run"], f["outer_run"]) for f in res.failed_runs} == {(i, j) for i in bad_rows for j in bad_outer}
    f = res.failed_runs[0]
    assert f["iteration"] == 0 and f["gains"][1] == 0.0 and f["noise"]["z1"] == 1.0
    assert f["error"] == "FloquetError: monodromy overflow"
    assert all(math.isnan(it0.responses[i][j]) for i in bad_rows for j in bad_outer)
    # a row with a failed pair scores as the worst row of its experiment
    worst = min(s for i, s in enumerate(it0.sn_ratios) if i not in bad_rows)
    assert all(it0.sn_ratios[i] == worst for i in bad_rows)
    assert "9 run(s) failed" in res.message
    buf = io.StringIO()
    dump_json(res.to_dict(), buf)
    d = json.loads(buf.getvalue())
    assert len(d["failed_runs"]) == 9 and d["iterations"][0]["responses"][bad_rows[0]][bad_outer[0]] is None


def test_a_failed_robust_confirmation_is_recorded():
    calls = {"n": 0}
    cfg = RobustConfig(tuning=TuningConfig(ranges=RANGES, max_evaluations=5000), noise=NOISE)

    def fail(g, n):  # serial: calls 82..90 are the first experiment's confirmation (9 x 9 runs before it)
        calls["n"] += 1
        return calls["n"] == 85

    res = robust_tune(_failing(fail), cfg)
    assert res.status == "converged"
    assert [f["run"] for f in res.failed_runs] == ["confirmation"] and res.failed_runs[0]["outer_run"] == 3
    it0 = res.iterations[0]
    assert math.isnan(it0.confirmation_sn) and math.isnan(it0.confirmation_responses[3])


def test_every_crossed_run_failing_is_one_clear_error():
    cfg = RobustConfig(tuning=TuningConfig(ranges=RANGES, max_evaluations=5000), noise=NOISE)
    with pytest.raises(ArithmeticError, match=r"every inner run of the first robust experiment failed") as e:
        robust_tune(_failing(lambda g, n: True), cfg)
    assert "\n" not in str(e.value) and "FloquetError: monodromy overflow" in str(e.value)


def test_a_programming_error_in_the_robust_objective_propagates():
    def obj(g, n):
        return objective(g, n) + 0.0 / g[1]  # ZeroDivisionError at g2 = 0: a bug, not a failed run

    cfg = RobustConfig(tuning=TuningConfig(ranges=RANGES, max_evaluations=5000), noise=NOISE)
    with pytest.raises(ZeroDivisionError):
        robust_tune(obj, cfg)
