"""``[robust]`` config section and ``flexstab tune --robust``.

The mechanism is tested model-free in test_taguchi_robust.py; here the
reduced model's noise mapping is checked against the model built by hand, and
the physics of the Omega noise against Floquet theory: with a fixed Floquet
exponent lambda the multiplier is rho = exp(lambda 2 pi / Omega), so
scaling Omega by s maps rho to rho^(1/s) -- nearly exactly for the strongly
controlled link, whose exponents hardly depend on Omega.
"""
from __future__ import annotations

import json
import math

import pytest

from flexstab.cli import main as cli_main
from flexstab.config import RobustSettings, load_config
from flexstab.robust import ReducedNoisePlant
from mbs_models.parameters import ManipulatorParameters
from mbs_models.reduced import ReducedModel
from stability import floquet


def test_robust_section_round_trip(tmp_path):
    f = tmp_path / "r.toml"
    f.write_text('[manipulator]\ntip_mass = 0.12\n[robust]\ntip_mass = [0.06, 0.3]\nomega_scale = [0.8, 1.2]\n'
                 'outer_array = "L9"\nsn = "smaller"\ngrid = 5\n')
    cfg = load_config(f)
    rs = cfg.robust
    assert rs.tip_mass == (0.06, 0.3) and rs.omega_scale == (0.8, 1.2) and rs.youngs_modulus_scale == (0.95, 1.05)
    noise = rs.noise_factors(cfg.manipulator.tip_mass)
    assert [n.name for n in noise] == ["tip_mass", "omega_scale", "youngs_modulus_scale"]
    assert noise[0].nominal == 0.12 and noise[1].nominal == 1.0
    assert rs.sn == "smaller" and rs.grid == 5 and rs.outer_array == "L9"
    assert load_config(None).robust == RobustSettings()


@pytest.mark.parametrize("text, word", [
    ("[robust]\ntip_mass = [0.2, 0.05]\n", "tip_mass"),
    ("[robust]\nomega_scale = [0, 1.1]\n", "omega_scale"),
    ("[robust]\nsn = \"larger\"\n", "sn"),
    ("[robust]\npayload = [0, 1]\n", "payload"),
    ("[robust]\ngrid = 1\n", "grid"),
])
def test_bad_robust_section(tmp_path, text, word):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ValueError, match=word):
        load_config(f)


def test_nominal_tip_mass_outside_noise_range_is_rejected():
    with pytest.raises(ValueError, match="nominal tip mass"):
        RobustSettings(tip_mass=(0.15, 0.2)).noise_factors(0.1)


def test_reduced_noise_plant_builds_the_perturbed_model():
    plant = ReducedNoisePlant(omega=4 * math.pi)
    m = plant({"tip_mass": 0.2, "omega_scale": 1.1, "youngs_modulus_scale": 0.95}).with_gains(20.0, 10.0)
    by_hand = ReducedModel(omega=4.4 * math.pi, kp=20.0, kd=10.0,
                           params=ManipulatorParameters(tip_mass=0.2, youngs_modulus=0.95 * 7.11e10))
    a, b = floquet(m), floquet(by_hand)
    # the same model up to ~1 ulp of Omega (4 pi * 1.1 vs 4.4 pi): equal to rounding (~1e-14) when both
    # adaptive runs stop at the same step count; a 1-ulp change can flip a step-doubling decision on
    # another BLAS, and then each run is within 10x its estimate (<= rtol 1e-9)
    tol = 1e-12 if a.n_steps == b.n_steps else 10 * (a.error_estimate + b.error_estimate)
    assert a.spectral_radius == pytest.approx(b.spectral_radius, rel=tol)


def test_omega_noise_acts_through_the_period():
    plant = ReducedNoisePlant(omega=4 * math.pi)
    gains = (39.0, 16.0)  # near the nominal Table 3-type tuning at 4 pi
    rho = floquet(plant({}).with_gains(*gains)).spectral_radius
    rho_fast = floquet(plant({"omega_scale": 1.1}).with_gains(*gains)).spectral_radius
    # rho^(1/1.1) if the exponent did not change; the exponent changes by a few 1e-3 here,
    # far less than the 12 % shift the period alone causes (a wrong mapping, e.g. Omega
    # not scaled, would give rho itself)
    assert rho_fast == pytest.approx(rho ** (1 / 1.1), rel=1e-2)
    assert abs(rho_fast - rho) > 0.1 * rho


def test_cli_tune_robust_json(tmp_path, capsys):
    f = tmp_path / "r.toml"
    f.write_text("[robust]\ngrid = 3\nmax_iterations = 2\n")
    rc = cli_main(["tune", "--robust", "--config", str(f), "--json"])
    d = json.loads(capsys.readouterr().out)
    assert rc == 0 and d["robust_design"]
    assert d["grid_size"] == 27 and d["robust"]["outer_array"].startswith("L9")
    assert d["worst_case_improvement"] == pytest.approx(d["nominal"]["worst"] - d["robust"]["check"]["worst"])
    assert len(d["robust"]["iterations"]) == 2


def test_cli_tune_robust_rejects_exudyn(capsys):
    assert cli_main(["tune", "--robust", "--model", "exudyn"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--robust" in err[0]


def test_tune_robust_output_carries_the_failed_runs(monkeypatch, capsys):
    """A ``FloquetError`` of one (inner, outer) run used to abort ``tune --robust``; now the run
    is in the JSON (``robust.failed_runs``) and the text output names it.  Model-free plant (a bowl in the
    gains, shifted by the noise) so the whole chain runs in well under a second."""
    import argparse
    import io

    import flexstab.commands.tune as tune_cmd
    from flexstab.options import dump_json
    from flexstab.robust import compare_nominal_robust
    from stability.floquet import FloquetError
    from taguchi.robust import NoiseFactor, RobustConfig
    from taguchi.tuning import TuningConfig

    class Plant:
        def __init__(self, m):
            self.m = m

        def spectral_measure(self, kp, kd):
            if kd == 0.0 and self.m > 1.0:
                raise FloquetError("monodromy overflow")
            return 0.3 + 0.01 * (kp - 3) ** 2 + 0.01 * (kd - 1) ** 2 + 0.001 * self.m

    ranges = ((0.0, 10.0), (0.0, 4.0))
    tcfg = TuningConfig(target=0.3, ranges=ranges, max_evaluations=400)
    rcfg = RobustConfig(tuning=TuningConfig(target=0.3, ranges=ranges, max_evaluations=10**5),
                        noise=(NoiseFactor("m", 0.9, 1.1, 1.0),), max_iterations=2)
    cmp = compare_nominal_robust(lambda n: Plant(n["m"]), tcfg, rcfg, grid_points=3)
    d = {"omega": 2 * math.pi, **cmp.to_dict(), "converged": cmp.nominal.converged}
    buf = io.StringIO()
    dump_json(d, buf)
    rob = json.loads(buf.getvalue())["robust"]
    assert rob["failed_runs"] and all(f["gains"][1] == 0.0 and f["noise"]["m"] > 1.0 for f in rob["failed_runs"])
    assert any(None in row for row in rob["iterations"][0]["responses"])
    monkeypatch.setattr(tune_cmd, "robust_report", lambda args: d)
    assert tune_cmd.run(argparse.Namespace(robust=True, json=False)) == (0 if d["converged"] else 1)
    out = capsys.readouterr().out
    f = rob["failed_runs"][0]
    assert (f"failed run (iteration 0, inner run {f['run']}, outer run {f['outer_run']}) at kp = {f['gains'][0]:.6g}, "
            f"kd = 0, noise m = 1.1: FloquetError: monodromy overflow") in out
