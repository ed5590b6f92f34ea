"""The library halves of ``flexstab validate`` and ``flexstab modes`` called from Python
(:mod:`flexstab.validation_runs`, :mod:`flexstab.mode_runs`): their option checks, their results against
independent values, and that the command line writes exactly what the library returns."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from flexstab.cli import main as cli_main
from flexstab.mode_runs import ANALYTIC_MATCH, ModesOptions, check_modes_options, matched_analytic, natural_frequencies
from flexstab.validation_runs import (CONFIG_FOR_MODEL_FILE, ValidateOptions, ValidateResult, check_validate_options,
                                      validate_multipliers)

HERE = Path(__file__).parent
PENDULUM = str(HERE / "models" / "vertical_pendulum.py")
OMEGA = 80.0


def _mathieu():
    """The damped Mathieu oracle of the support-driven pendulum (scipy DOP853, written without the package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_cl_oracles_vr", HERE / "test_constrained_linearisation.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.mathieu_multipliers(OMEGA, mod._pend.AMPLITUDE, mod._pend.DAMPING, False)


@pytest.fixture(scope="module")
def pendulum() -> ValidateResult:
    # one refinement (h, h/2): an error bar but no verdict -- cheap, and enough to compare with the oracle
    return validate_multipliers(ValidateOptions(model=PENDULUM, omega=OMEGA, refinements=1))


def test_library_measurement_against_the_mathieu_oracle(pendulum):
    d = pendulum.to_dict()
    assert isinstance(pendulum, ValidateResult) and d is pendulum.report
    assert d["model"] == "vertical_pendulum" and d["drives"] == [] and d["kp"] == [] and d["kd"] == []
    assert d["gains_source"] == "none given (0 for every drive)"
    ref = _mathieu()
    assert len(pendulum.measurement.measured) == 2
    for m, e in zip(pendulum.measurement.measured, pendulum.measurement.errors):
        assert np.min(np.abs(ref - m)) <= e
    # the bar is tight enough to reject the oracle's multipliers moved by 1 % of their modulus
    assert all(np.min(np.abs(1.01 * ref - m)) > e for m, e in zip(pendulum.measurement.measured,
                                                                  pendulum.measurement.errors))
    assert not pendulum.agrees  # two step levels show no convergence order: no verdict


def test_cli_writes_what_the_library_returns(pendulum, tmp_path, capsys):
    rc = cli_main(["validate", "--model", PENDULUM, "--omega", str(OMEGA), "--refinements", "1", "--json",
                   "--out", str(tmp_path)])
    printed = json.loads(capsys.readouterr().out)
    written = json.loads((tmp_path / "validation.json").read_text())
    assert rc == 1  # no verdict: a check that did not pass
    lib = json.loads(json.dumps(pendulum.report, default=float))
    lib.pop("timings")
    for d in (printed, written):
        d.pop("timings")
        _same(d, lib)


def _same(a, b, path="") -> None:
    """Equal keys, strings, booleans and integers; floats equal to rounding (1e-10: the multipliers are O(1),
    and the command line runs its linear algebra on one BLAS thread, the test process on its default)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), path
        for k in a:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and not isinstance(b, bool):
        assert b == pytest.approx(a, rel=1e-9, abs=1e-10), path
    else:
        assert a == b, path


@pytest.mark.parametrize("over, message", [
    ({"refinements": 5}, "--refinements must be <= 4"),
    ({"refinements": -1}, "--refinements must be >= 0"),
    ({"samples": 7}, "--samples must be even"),
    ({"samples": 2}, "--samples must be >= 4"),
    ({"step": 0.0}, "--step must be > 0"),
    ({"amplitude": -1.0}, "--amplitude must be > 0"),
    ({"compare": 0}, "--compare must be >= 1"),
    ({"spectral_radius": 1.5}, "--spectral-radius must be in [0, 1]"),
    ({"kp": (1.0, 2.0)}, "the built-in single link has one drive"),
    ({"kd": (-1.0,)}, "--kd must be >= 0"),
    ({"elements": 0}, "--elements must be >= 1"),
    ({"workers": 0}, "--workers must be >= 1"),
    ({"full_map": True}, "--full-map applies to model files"),
    ({"predict_reference": "rigid"}, "accepts only 'periodic'"),
    ({"model": "missing.py"}, "model file 'missing.py' not found"),
    ({"model": PENDULUM, "elements": 4}, "--elements applies to the built-in models only"),
])
def test_option_checks_reject_each_bad_value(over, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        check_validate_options(ValidateOptions(**over))
    check_validate_options(ValidateOptions())  # the defaults pass


def test_model_file_refuses_a_configuration_and_a_step_beyond_the_period():
    from flexstab.config import StudyConfig

    with pytest.raises(ValueError, match=CONFIG_FOR_MODEL_FILE.replace("-", r"\-")):
        validate_multipliers(ValidateOptions(model=PENDULUM), StudyConfig())
    with pytest.raises(ValueError, match="smaller than the period"):
        validate_multipliers(ValidateOptions(model=PENDULUM, omega=OMEGA, step=2 * math.pi / OMEGA))


# ----------------------------------------------------------------------------- modes
def test_matched_analytic_stops_at_the_first_mismatch():
    assert matched_analytic([10.0, 20.0, 30.0], [10.2, 20.5, 40.0]) == [10.2, 20.5]
    # just inside and just outside the match tolerance
    assert matched_analytic([1.0 + 0.99 * ANALYTIC_MATCH], [1.0]) == [1.0]
    assert matched_analytic([1.0 + 1.01 * ANALYTIC_MATCH], [1.0]) == []


def test_modes_option_checks():
    for bad, message in (({"elements": 0}, "--elements"), ({"count": 0}, "--count"), ({"hub": "free"}, "--hub")):
        with pytest.raises(ValueError, match=message):
            check_modes_options(ModesOptions(**bad))


def test_natural_frequencies_from_python_converge_at_fourth_order_and_match_the_cli(capsys):
    # the clamped link's two lowest Euler-Bernoulli frequencies (tip mass included), from the roots of the
    # frequency equation in test_exudyn_modes.py (written without the package)
    clamped_hz = [17.2052, 112.409]
    coarse = natural_frequencies(ModesOptions(elements=4, count=2))
    fine = natural_frequencies(ModesOptions(elements=8, count=2))
    assert list(coarse.analytic_hz) == pytest.approx(clamped_hz, rel=1e-5)
    # cubic (ANCF) beam elements: frequency errors fall as h^4, so halving the elements divides them by ~16
    order = np.log2(np.abs(coarse.relative_errors) / np.abs(fine.relative_errors))
    assert np.all((order > 3.5) & (order < 4.5)), order
    assert cli_main(["modes", "--elements", "4", "--count", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(coarse.to_dict()))
