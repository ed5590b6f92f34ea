"""The built-in anisotropic Laval rotor (``laval-rotor``) against its closed form (tests/_laval_oracle.py).

The package's path -- the Exudyn model file, its periodic orbit (gravity makes it non-trivial), the
linearisation read from Exudyn, the frozen-modal Floquet engine -- against the hand-derived shaft-fixed
equations (constant coefficients: exact multipliers over one turn), and ``flexstab campbell`` on it against the
closed-form principal frequencies, where sorting by frequency would swap the two whirl branches across the
instability band.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

import _laval_oracle as oracle  # tests/ helper

pytest.importorskip("exudyn")

#: Agreement required of the multipliers: the adaptive engine's rtol is 1e-9; the linearisation reads
#: Exudyn's numerical Jacobian of the shaft's user function (measured total: <= 3.5e-9 over 20..250 rad/s).
MULTIPLIER_TOLERANCE = 1e-8


def _max_distance(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(max(np.min(np.abs(b - x)) for x in a))


@pytest.fixture(scope="module")
def analyses():
    from linearize import analyze

    return {W: analyze("laval-rotor", W, n_steps=None) for W in (30.0, 107.0, 200.0)}


@pytest.mark.parametrize("W", [30.0, 107.0, 200.0])
def test_multipliers_equal_the_closed_form(analyses, W):
    res = analyses[W]
    mu = np.asarray(res.floquet.multipliers)
    assert res.orbit.residual < 1e-9  # a real (gravity-sagged, 2 Omega-modulated) orbit was found
    assert _max_distance(mu, oracle.multipliers(W)) < MULTIPLIER_TOLERANCE
    # the comparison can fail: a speed 1e-6 off, or the shaft's anisotropy dropped, is far outside it
    assert _max_distance(mu, oracle.multipliers(W * (1 + 1e-6))) > 100 * MULTIPLIER_TOLERANCE
    iso = {"stiffness_xi": 2.3e4, "stiffness_eta": 2.3e4}
    assert _max_distance(mu, oracle.multipliers(W, **{**oracle.ROTOR, **iso})) > 1e-3


def test_unstable_between_the_shaft_frequencies(analyses):
    # undamped the band is sqrt(k_xi/m) = 100 .. sqrt(k_eta/m) = 114.0 rad/s; 107 rad/s is inside
    assert analyses[107.0].floquet.spectral_radius > 1.2
    assert analyses[30.0].floquet.spectral_radius < 1.0 and analyses[200.0].floquet.spectral_radius < 1.0
    assert analyses[107.0].floquet.spectral_radius == pytest.approx(np.max(np.abs(oracle.multipliers(107.0))),
                                                                     abs=MULTIPLIER_TOLERANCE)


def test_gravity_does_not_change_the_multipliers():
    from linearize import analyze

    a = analyze("laval-rotor", 50.0, n_steps=None, gravity=0.0)
    b = analyze("laval-rotor", 50.0, n_steps=None)
    assert np.max(np.abs(b.orbit.q)) > 1e-3 > np.max(np.abs(a.orbit.q))
    assert _max_distance(a.floquet.multipliers, b.floquet.multipliers) < MULTIPLIER_TOLERANCE


def test_bad_rotor_options_are_one_line_errors():
    from mbs_models.model_file import ModelFileError, build_model, builtin_model

    with pytest.raises(ModelFileError, match="stiffness_eta must be finite and > 0"):
        build_model(builtin_model("laval-rotor", stiffness_eta=-1.0), 50.0)


def test_campbell_bad_input_exits_2_with_one_line(capsys):
    from flexstab.cli import main

    for argv in (["--omega-range", "50,20"], ["--omega-range", "50"], ["--omega-range", "a,b"]):
        with pytest.raises(SystemExit) as exc:
            main(["campbell", "--model", "laval-rotor", *argv])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--omega-range" in err
    for argv, what in ((["--points", "1"], "--points"), (["--model", "reduced"], "model file")):
        args = ["campbell", "--model", "laval-rotor", "--omega-range", "10,20", *argv]
        assert main(args) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and what in err


@pytest.mark.slow
def test_campbell_command_tracks_the_whirl_branches(tmp_path, capsys):
    from flexstab.cli import main

    speeds = np.linspace(60.0, 170.0, 12)
    rc = main(["campbell", "--model", "laval-rotor", "--omega-range", "60,170", "--points", "12", "--json",
               "--out", str(tmp_path)])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    for key in ("figures", "csv", "json"):
        paths = s[key] if isinstance(s[key], list) else [s[key]]
        assert all((tmp_path / p.split("/")[-1]).exists() for p in paths)
    np.testing.assert_allclose(s["omegas"], speeds)
    # every point: the modes' principal frequencies and damping ratios are the closed form's
    for W, p in zip(speeds, s["points"]):
        got = sorted((m["frequency"], m["damping_ratio"]) for m in p["modes"])
        exact = oracle.principal_modes(W)
        assert len(got) == len(exact)
        for (f, z), (fe, ze, _) in zip(got, exact):
            assert f == pytest.approx(fe, rel=1e-7)
            assert z == pytest.approx(ze, rel=1e-4, abs=1e-7)
    # the upper shaft-frame mode (never real, never crossing its partner in the shaft frame) is one branch
    # present at every speed; in the inertial frame it is the upper curve below the band and the lower above
    upper = np.array([_upper_rotating(W) for W in speeds])
    full = [b for b in s["branches"] if all(v is not None for v in b["frequency_hz"])]
    assert any(np.allclose(np.array(b["frequency_hz"]) * 2 * math.pi, upper, rtol=1e-7) for b in full)
    # sorting by frequency puts the other mode on the "upper" curve above the band: that check rejects it
    by_rank = np.array([max(m["frequency"] for m in p["modes"]) for p in s["points"]])
    assert not np.allclose(by_rank, upper, rtol=1e-3)


def _upper_rotating(W):
    """Principal frequency of the upper shaft-frame mode (the one with the larger rotating-frame frequency)."""
    lam, V = np.linalg.eig(oracle.rotating_matrix(W))
    i = int(np.argmax(lam.imag))
    l, v = lam[i], V[:, i]
    a = np.linalg.norm(oracle.P_PLUS @ v[:2]) ** 2
    b = np.linalg.norm(oracle.P_MINUS @ v[:2]) ** 2
    rep = l + 1j * W if a >= b else l - 1j * W
    return abs(rep.imag)


@pytest.mark.slow
def test_study_runs_the_rotor_by_name(tmp_path):
    from flexstab.cli import main

    assert main(["study", "--model", "laval-rotor", "--omega", "80", "--quick", "--out", str(tmp_path)]) == 0
    fl = json.loads((tmp_path / "floquet.json").read_text())
    mu = np.array([complex(*m) for m in fl["floquet"]["multipliers"]])
    # the study's fixed 128-step solve certifies the moduli: within its own step-doubling estimate (relative)
    exact = np.sort(np.abs(oracle.multipliers(80.0)))
    assert np.max(np.abs(np.sort(np.abs(mu)) - exact) / exact) <= fl["error_estimate"]
    assert _max_distance(mu, oracle.multipliers(80.0 * 1.0001)) > fl["error_estimate"]
    assert json.loads((tmp_path / "validation.json").read_text())["agrees"] is True
