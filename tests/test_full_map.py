"""The full one-period map measured from random perturbations (:mod:`validation.full_map`).

Oracles: the exact monodromy ``expm(A T)`` of a constant first-order system, and the trapezoidal
rule's own one-period map ``((I - hA/2)^-1 (I + hA/2))^(T/h)`` as the "nonlinear runs" -- the
integrator the model path uses, applied exactly, so the test sees its damping law (an unresolved
mode's ``ln|mu_h| = ln|mu| / (1 + (omega h / 2)^2)``) and nothing else.
"""
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest
import scipy.linalg

from validation.full_map import (
    FullMapConfig,
    compare_full_map,
    extrapolate_modulus,
    measure_full_map,
)
from validation.multipliers import energy_norm

from test_multipliers import _oracles  # tests/ module: the pendulum model and its Mathieu oracle

T = 1.0
#: (decay sigma in 1/s, angular frequency in rad/s) per oscillator: a slow lightly damped fast mode
#: (|mu| = exp(-0.585) = 0.557, the two-link's axial pair at a smaller frequency), a strongly damped
#: fast mode (|mu| = 2e-5) and a non-oscillating drive-like mode pair (|mu| = 0.3 and 0.0007).
MODES = ((0.585, 2 * math.pi * 900.0), (10.8, 2 * math.pi * 3000.0))
REAL = (math.log(0.3), math.log(7e-4))


def _system() -> np.ndarray:
    blocks = [np.array([[-s, w], [-w, -s]]) for s, w in MODES] + [np.diag(REAL)]
    A = scipy.linalg.block_diag(*blocks)
    S = np.eye(A.shape[0]) + 0.3 * np.random.default_rng(1).standard_normal(A.shape)  # not normal
    return S @ A @ np.linalg.inv(S)


def _trapezoidal_images(A: np.ndarray):
    I = np.eye(A.shape[0])

    def images(h, D):
        n = int(round(T / h))
        step = np.linalg.solve(I - 0.5 * h * A, I + 0.5 * h * A)
        return np.linalg.matrix_power(step, n) @ D

    return images


@pytest.fixture(scope="module")
def measured():
    A = _system()
    norm = energy_norm(np.eye(3), np.eye(3))
    cfg = FullMapConfig(step=T / 2048, refinements=3, amplitude=1e-2, slowest=6)
    exact = np.linalg.eigvals(scipy.linalg.expm(A * T))
    return measure_full_map(_trapezoidal_images(A), norm, cfg), exact


def _exact_labels(exact):
    mods = np.abs(exact)
    return [("slow pair" if abs(m - 0.557) < 0.01 else "drive" if abs(m - 0.3) < 0.01 else "other")
            for m in mods]


def test_unresolved_slow_mode_is_measured_within_its_bar(measured):
    res, exact = measured
    slow = math.exp(-MODES[0][0])
    # omega h = 2.8 .. 0.35 at T/2048 .. T/16384: the coarse levels do not resolve the mode
    assert not res.diverged and res.n_perturbations == 6
    top = res.multipliers[0]
    assert abs(top.levels[0]) > 0.6  # the trapezoidal rule leaves it near the unit circle there
    assert top.resolved and abs(top.modulus - slow) <= top.error_bar
    assert top.error_bar < 1e-2 * slow
    # the law's ratio of the 1/ln|mu_h| changes, to its h^4 term
    assert top.observed_ratio == pytest.approx(4.0, rel=0.05)
    drive = [m for m in res.multipliers if abs(m.modulus - 0.3) < 0.01]
    assert drive and abs(drive[0].modulus - 0.3) <= drive[0].error_bar


def test_strongly_damped_mode_is_not_reported_as_slow(measured):
    res, _ = measured
    # its trapezoidal one-period multiplier at T/2048 is exp(-10.8 / (1 + (omega h / 2)^2)) = 0.61, a
    # spurious slow multiplier; extrapolated along the law it is ~2e-5 and drops below the floor
    sigma, omega = MODES[1]
    spurious = math.exp(-sigma * T / (1 + (omega * res.steps[0] / 2) ** 2))
    assert spurious > 0.5
    assert all(abs(m.modulus - spurious) > 0.05 for m in res.multipliers)
    assert len([m for m in res.multipliers if m.resolved]) == 3  # the slow pair and the 0.3 drive mode


def test_full_prediction_agrees_and_one_without_the_slow_mode_is_rejected(measured):
    res, exact = measured
    labels = _exact_labels(exact)
    full = compare_full_map(res, exact, labels)
    assert full.agrees and not full.unmatched
    keep = [i for i, lab in enumerate(labels) if lab != "slow pair"]
    missing = compare_full_map(res, exact[keep], [labels[i] for i in keep])
    assert not missing.agrees
    assert len(missing.unmatched) == 2
    assert all(abs(u["modulus"] - math.exp(-MODES[0][0])) < 1e-2 for u in missing.unmatched)


def test_prediction_two_percent_off_is_rejected(measured):
    res, exact = measured
    wrong = np.where(np.abs(np.abs(exact) - 0.557) < 0.01, 1.02 * exact, exact)
    assert not compare_full_map(res, wrong, _exact_labels(exact)).agrees


def test_extrapolation_is_exact_on_the_law_and_refuses_another_order():
    L, c = math.log(0.557), 40.0
    law = [complex(math.exp(L / (1 + c * h * h))) for h in (1.0, 0.5, 0.25)]
    value, bar, q, ok = extrapolate_modulus(law)
    assert ok and q == pytest.approx(4.0, rel=1e-9) and value == pytest.approx(0.557, rel=1e-9)
    # a first-order approach (e.g. a drifting constraint) has ratio 2: not resolved
    first = [complex(0.557 + 0.05 * h) for h in (1.0, 0.5, 0.25)]
    assert not extrapolate_modulus(first)[3]


@pytest.mark.parametrize("kwargs", [dict(refinements=5), dict(slowest=0), dict(step=-1.0), dict(amplitude=0.0),
                                    dict(perturbations=0), dict(floor=1.5)])
def test_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        FullMapConfig(**kwargs)


def test_too_few_perturbations_for_the_full_map():
    norm = energy_norm(np.eye(3), np.eye(3))
    with pytest.raises(ValueError, match="needs >= 6"):
        measure_full_map(lambda h, D: D, norm, FullMapConfig(step=0.1, amplitude=1e-2, perturbations=4))


def test_failing_run_is_reported_not_raised():
    norm = energy_norm(np.eye(1), np.eye(1))

    def images(h, D):
        raise RuntimeError("Newton failed")

    res = measure_full_map(images, norm, FullMapConfig(step=0.1, amplitude=1e-2))
    assert res.diverged and "Newton failed" in res.reason and not res.multipliers
    assert not compare_full_map(res, [0.3], ["x"]).agrees


# --------------------------------------------------------------------------- nonlinear runs (Exudyn)
OMEGA_K, AMP_K = 80.0, 0.05  # Kapitza pendulum: support amplitude 5 cm at 80 rad/s, upright


@pytest.fixture(scope="module")
def kapitza():
    from validation.full_map import measure_model_full_map

    o = _oracles()
    T_k = 2 * math.pi / OMEGA_K
    res, runner = measure_model_full_map(o.PENDULUM, OMEGA_K, config=FullMapConfig(step=T_k / 128, refinements=2),
                                         amplitude=AMP_K, inverted=True)
    return res, runner, o


@pytest.mark.slow
def test_kapitza_pendulum_full_map_against_mathieu(kapitza):
    # oracle: the damped Mathieu equation (scipy DOP853, independent of Exudyn and of the package)
    res, runner, o = kapitza
    ref = o.mathieu_multipliers(OMEGA_K, AMP_K, o._pend.DAMPING, True)
    assert runner.rheonomic and "generalised-alpha" in res.integrator  # the driven support: index 3
    assert not res.diverged and res.state_dimension == 2 == res.n_perturbations
    assert len(res.multipliers) == 2
    for m in res.multipliers:
        assert m.resolved
        # rho_inf = 0.9 damps the resolved pair at O(h^2): the levels converge with the law's ratio 4
        assert m.observed_ratio == pytest.approx(4.0, rel=0.05)
        assert abs(abs(m.levels[0]) - abs(ref[0])) > 10 * m.error_bar  # the coarsest level alone is off
        assert abs(m.modulus - abs(ref[0])) <= m.error_bar
    assert compare_full_map(res, ref, ["pendulum", "pendulum"]).agrees
    # rejected: a prediction without the pair, and Mathieu's pair for 10 % more joint damping (only moduli
    # are compared: a complex pair's modulus is sqrt(det Phi), which the support amplitude does not change)
    assert compare_full_map(res, [], []).unmatched
    wrong = o.mathieu_multipliers(OMEGA_K, AMP_K, 1.1 * o._pend.DAMPING, True)
    assert abs(abs(wrong[0]) - abs(ref[0])) < 1e-3  # a small difference, far beyond the bars
    assert not compare_full_map(res, wrong, ["pendulum", "pendulum"]).agrees


@pytest.mark.slow
def test_cli_full_map_json_and_exit_code(capsys):
    import json

    from flexstab.cli import main

    o = _oracles()
    rc = main(["validate", "--model", str(o.PENDULUM), "--omega", str(OMEGA_K), "--full-map", "--workers", "1",
               "--step", str(2 * math.pi / OMEGA_K / 128), "--full-map-step", str(2 * math.pi / OMEGA_K / 128),
               "--json"])
    d = json.loads(capsys.readouterr().out)
    fm = d["full_map"]
    for key in ("multipliers", "error_bars", "unmatched", "n_perturbations", "steps", "partners", "agrees"):
        assert key in fm
    # the model file's default: the hanging pendulum on the vibrating support, against Mathieu
    ref = o.mathieu_multipliers(OMEGA_K, o._pend.AMPLITUDE, o._pend.DAMPING, False)
    assert fm["agrees"] and not fm["unmatched"] and rc == 0
    assert all(abs(m - abs(ref[0])) <= e for m, e in zip(fm["multipliers"], fm["error_bars"]))


@pytest.mark.parametrize("level", [0, -1])
def test_amplitude_error_measured_at_one_level_covers_a_quadratic_bias(level):
    """Runs with a quadratic term (one-sided perturbations: every fitted level is biased by ``c a``).
    With the half-amplitude repeat -- at the coarsest level or at the finest -- every measured modulus
    is within its bar of an exact multiplier; without it one is not (the check can fail)."""
    A = _system()
    linear = _trapezoidal_images(A)
    norm = energy_norm(np.eye(3), np.eye(3))
    exact = np.abs(np.linalg.eigvals(scipy.linalg.expm(A * T)))

    def images(h, D):
        X = linear(h, D)
        return X + 0.3 * X * X

    def misses(check):
        cfg = FullMapConfig(step=T / 2048, refinements=3, amplitude=1e-2, slowest=6, amplitude_check=check,
                            amplitude_level=level)
        res = measure_full_map(images, norm, cfg)
        assert res.multipliers and not res.diverged
        return [m.modulus for m in res.multipliers if np.min(np.abs(exact - m.modulus)) > m.error_bar]

    assert misses(True) == []
    assert misses(False), "without the amplitude check the biased modulus must fall outside its bar"


def test_amplitude_level_must_name_a_step_level():
    with pytest.raises(ValueError, match="amplitude_level"):
        FullMapConfig(step=0.1, refinements=2, amplitude_level=3)
