"""Input validation and output contracts of the API and the CLI."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from flexstab.cli import main as cli_main
from mbs_models.parameters import ManipulatorParameters
from mbs_models.reduced import ReducedModel, derived_mode_constants
from stability import SecondOrderPeriodicSystem, floquet
from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune


def test_complex_P_is_rejected_not_cast():
    with pytest.raises(ValueError, match="real-valued"):
        floquet(lambda t: np.array([[0, 1], [1j, 0]]), period=1.0)


def test_period_conflicting_with_the_objects_own_period():
    with pytest.raises(ValueError, match="conflicts"):
        floquet(ReducedModel(omega=2 * math.pi), period=0.5)
    # the same period is fine
    same = floquet(ReducedModel(omega=2 * math.pi), period=1.0).spectral_radius
    # the same computation as without ``period`` (T = 2 pi / 2 pi = 1.0 exactly) ...
    assert same == floquet(ReducedModel(omega=2 * math.pi)).spectral_radius
    # ... and the paper's Table 2 (p. 489), 13.7797, to its 4 significant digits (as test_table2)
    assert same == pytest.approx(13.7797, rel=2e-4)


@pytest.mark.parametrize("period", [True, "1"])
def test_period_must_be_a_number(period):
    with pytest.raises(ValueError, match="period"):
        floquet(lambda t: np.eye(2), period=period)


def test_mass_vanishing_inside_the_period():
    sys_ = SecondOrderPeriodicSystem(1.0, lambda t: [[math.cos(math.pi * t) ** 2]], lambda t: [[1.0]],
                                     lambda t: [[1.0]])
    with pytest.raises(ValueError, match="singular"):
        floquet(sys_)


def test_paper_constants_belong_to_the_paper_link():
    other = ManipulatorParameters(length=0.5, tip_mass=1.0)
    with pytest.raises(ValueError, match="length = 0.9"):
        ReducedModel(params=other, constants="paper")
    auto = ReducedModel(params=other)  # default "auto": derived constants for this link
    assert auto.mode.source == "derived"
    assert auto.mode.C1 == pytest.approx(derived_mode_constants(0.5).C1)
    assert ReducedModel().mode.source == "paper"


def test_tuned_gains_stay_inside_the_user_ranges():
    """Paper Eq. (12): u_min <= u <= u_max; the windows are shifted, never leave the ranges."""
    cfg = TuningConfig(target=0.3, kp_range=(0.0, 60.0), kd_range=(0.0, 40.0))
    res = taguchi_tune(GainObjective(ReducedModel(omega=4 * math.pi)), cfg)
    assert res.converged
    assert 0.0 <= res.kp <= 60.0 and 0.0 <= res.kd <= 40.0
    for it in res.iterations:
        assert 0.0 <= it.kp_range[0] < it.kp_range[1] <= 60.0
        assert 0.0 <= it.kd_range[0] < it.kd_range[1] <= 40.0


def test_tune_exit_code_does_not_depend_on_json(capsys):
    argv = ["tune", "--target", "100", "--max-evaluations", "30"]
    assert cli_main(argv) == 1
    capsys.readouterr()
    assert cli_main(argv + ["--json"]) == 1
    out = capsys.readouterr()
    assert json.loads(out.out)["converged"] is False
    assert "not converged" in out.err


def test_json_output_is_strict(capsys):
    # the paper method cannot form det Phi of the controlled case (it underflows):
    # the residual is reported as null, never as the non-standard token Infinity
    assert cli_main(["floquet", "--json", "--method", "paper", "--omega", "8pi", "--kp", "23.0147",
                     "--kd", "6.8628"]) == 0
    text = capsys.readouterr().out
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON token {c}"))


@pytest.mark.parametrize("text", ["manipulator = 3\n", "[[manipulator]]\nlength = 1.0\n", "study = [1, 2]\n"])
def test_config_sections_must_be_tables(tmp_path, text, capsys):
    f = tmp_path / "c.toml"
    f.write_text(text)
    assert cli_main(["floquet", "--config", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "table" in err[0]


def test_study_rejects_a_bad_scheduler_before_working(tmp_path, capsys):
    assert cli_main(["study", "--quick", "--scheduler", "foo", "--out", str(tmp_path)]) == 2
    assert "scheduler" in capsys.readouterr().err
    assert not (tmp_path / "report.md").exists()


def test_fine_mesh_clamped_beam_keeps_its_first_mode(capsys):
    """At 260 elements the first bending eigenvalue is ~1e-13 of the largest (axial) one; it must not be
    mistaken for a rigid-body mode, and --json must stay pure JSON despite Exudyn's size warning."""
    assert cli_main(["modes", "--elements", "260", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["rigid_modes"] == 0
    # 17.2052045 Hz: Euler-Bernoulli with tip mass (beta l = 1.71917; test_exudyn_modes solves the
    # frequency equation).  The mesh error is O(h^4) ~ 1e-11 here, so rounding dominates: eigh on (K, M)
    # is backward stable, |d lambda_1| <~ eps lambda_max, and lambda_max / lambda_1 <= 1e13 (docstring):
    # rel. frequency error <= eps 1e13 / 2 = 1.1e-3 (measured 3.5e-6; the next mode, 112 Hz, is far outside)
    assert d["frequencies_hz"][0] == pytest.approx(17.2052045, rel=0.5 * np.finfo(float).eps * 1e13)


def test_exudyn_only_flags_rejected_for_the_reduced_model(capsys):
    assert cli_main(["floquet", "--elements", "4"]) == 2
    assert "--model exudyn only" in capsys.readouterr().err
