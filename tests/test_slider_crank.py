"""The built-in slider-crank (flexible ANCF rod, constant crank speed) against a finite-difference monodromy of
the nonlinear model computed from Exudyn runs alone (tests/_slider_crank_oracle.py: its own shooting orbit,
central differences, the trapezoidal rule at three step levels, Richardson-extrapolated)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("exudyn")

import _slider_crank_oracle as oracle  # tests/ helper

OMEGA = 150.0
#: Required agreement of the four largest multipliers (|rho| 0.69 and 7e-4): the oracle's extrapolated error
#: estimate (3e-6 at 1000/2000/4000 steps per period) plus the package's engine tolerance (rtol 1e-9).
TOLERANCE = 1e-5


def _matched_distance(ref, got) -> float:
    pool = list(np.asarray(got, dtype=complex))
    worst = 0.0
    for m in np.asarray(ref, dtype=complex):
        j = int(np.argmin([abs(m - p) for p in pool]))
        worst = max(worst, abs(m - pool.pop(j)))
    return worst


@pytest.fixture(scope="module")
def reference():
    return oracle.multipliers(OMEGA, steps=1000)


@pytest.mark.slow
def test_constant_speed_crank_matches_the_finite_difference_monodromy(reference):
    from linearize import analyze

    # the oracle's own premises: a periodic orbit, second-order convergence in the step, a small estimate
    assert reference["defect"] < 1e-7
    assert 3.6 < reference["ratio"] < 4.4
    assert reference["estimate"] < TOLERANCE / 3
    res = analyze("slider-crank", OMEGA, form="constraint", n_steps=None)
    mu = np.asarray(res.floquet.multipliers)[:4]
    assert res.linearization.size == 9
    assert _matched_distance(reference["extrapolated"], mu) < TOLERANCE
    # the comparison can fail: the oracle's coarsest level (not extrapolated) and a 10 % heavier slider
    assert _matched_distance(reference["levels"][0], mu) > 100 * TOLERANCE
    heavier = analyze("slider-crank", OMEGA, form="constraint", n_steps=None, slider_mass=0.11)
    assert _matched_distance(reference["extrapolated"], np.asarray(heavier.floquet.multipliers)[:4]) > 10 * TOLERANCE


def test_bad_options_are_one_line_errors():
    from mbs_models.model_file import ModelFileError, build_model, builtin_model

    with pytest.raises(ModelFileError, match="must be longer than the crank"):
        build_model(builtin_model("slider-crank", rod=0.1), OMEGA)
    with pytest.raises(ModelFileError, match="form must be"):
        build_model(builtin_model("slider-crank", form="belt"), OMEGA)


KP, KD = 20.0, 0.2


@pytest.mark.slow
def test_drive_form_under_pd_matches_the_finite_difference_monodromy(reference):
    """The natural drive form, motion (Omega t, Omega, 0), released under feed-forward + PD."""
    from linearize import analyze

    closed = oracle.closed_loop_multipliers(reference, OMEGA, KP, KD)
    assert closed["defect"] < 1e-7 and 3.6 < closed["ratio"] < 4.4 and closed["estimate"] < TOLERANCE / 3
    res = analyze("slider-crank", OMEGA, kp=KP, kd=KD, n_steps=None)
    assert res.linearization.size == 10  # the crank angle is released
    mu = np.asarray(res.floquet.multipliers)[:4]
    assert _matched_distance(closed["extrapolated"], mu) < TOLERANCE
    # the comparison can fail: the constant-speed multipliers (crank held) and the coarsest level
    assert _matched_distance(closed["extrapolated"], reference["extrapolated"]) > 100 * TOLERANCE
    assert _matched_distance(closed["levels"][0], mu) > 100 * TOLERANCE
