"""``flexstab chart --model PATH.py``: chart values against independent Floquet analyses.

Oracles (written independently of the package, in tests/test_constrained_linearisation.py):

* vertical pendulum on a driven support (no drives): the damped Mathieu equation integrated by
  scipy (DOP853, rtol 1e-12) -- the Omega chart, whose orbits are continued point to point;
* rigid double pendulum with two drives: the hand-derived linearisation integrated by scipy --
  the gain chart of one drive with the other drive's gains fixed.

Tolerance: each chart value is the Richardson-extrapolated ``magnus2`` product in the frozen-modal
frame (:meth:`linearize.analysis.ModelPlant.floquet`), 4th order, so the error of ``N`` steps is
``~ 16/15 |r_N - r_2N|`` asymptotically; ``4/3 |r_N - r_2N|`` bounds it for any observed order
``p >= 2`` (``2^p / (2^p - 1)`` falls with ``p``).  The test runs the chart at ``N`` and ``2N`` and allows
twice that (pre-asymptotic margin, not derived) plus 1e-8 for
the orbit / linearisation (tolerance 1e-10) and the oracle's DOP853 (~1e-10).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from flexstab.cli import main as cli_main
from test_constrained_linearisation import DOUBLE, PENDULUM, _pend, double_pendulum_multipliers, mathieu_multipliers

UNDAMPED = 2e-3  # linearize.analysis.UNDAMPED_TOLERANCE: the chart's response skips |rho| within it of 1


def dominant(mu) -> float:
    """The chart's response rule applied to the oracle: largest modulus off the unit circle."""
    m = np.sort(np.abs(np.asarray(mu)))[::-1]
    off = m[np.abs(m - 1.0) >= UNDAMPED]
    return float(off[0] if off.size else m[0])


def chart(tmp_path, capsys, *argv) -> dict:
    rc = cli_main(["chart", *argv, "--out", str(tmp_path), "--json"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    return json.loads(out.out)


@pytest.mark.slow
def test_omega_chart_of_a_driveless_model_is_the_damped_mathieu_chart(tmp_path, capsys):
    """Support-driven pendulum near its first parametric resonance (2 w0 ~ 10.7 rad/s)."""
    argv = ["--model", PENDULUM, "--omega", "10.7", "--omega-range", "10", "11.5", "--omega-points", "4"]
    a = chart(tmp_path / "a", capsys, *argv, "--steps", "256")
    b = chart(tmp_path / "b", capsys, *argv, "--steps", "512")
    assert a["gain_chart"] is None and a["drives"] == [] and "no drives" in a["note"]
    oc = a["omega_chart"]
    r_n = np.array(oc["spectral_radius_uncontrolled"])
    r_2n = np.array(b["omega_chart"]["spectral_radius_uncontrolled"])
    np.testing.assert_array_equal(r_n, oc["spectral_radius_controlled"])  # no gains to apply
    ref = np.array([dominant(mathieu_multipliers(w, _pend.AMPLITUDE, _pend.DAMPING, False)) for w in oc["omega"]])
    tol = 2 * 4 / 3 * np.abs(r_n - r_2n) + 1e-8
    assert np.all(np.abs(r_n - ref) <= tol), (r_n, ref, tol)
    # the check can fail: without the support motion (a = 0) the chart would be a constant decay
    still = np.array([dominant(mathieu_multipliers(w, 0.0, _pend.DAMPING, False)) for w in oc["omega"]])
    assert np.max(np.abs(r_n - still) - tol) > 1e-3


@pytest.mark.slow
def test_gain_chart_of_one_drive_with_the_other_fixed(tmp_path, capsys):
    """Double pendulum: (kp, kd) of the elbow varied, the shoulder at kp = 5, kd = 0.5."""
    argv = ["--model", DOUBLE, "--drive", "elbow", "--kp", "5,0", "--kd", "0.5,0", "--grid", "3",
            "--kp-range", "0", "4", "--kd-range", "0", "1", "--omega-points", "2", "--no-taguchi"]
    a = chart(tmp_path / "a", capsys, *argv, "--steps", "256")
    b = chart(tmp_path / "b", capsys, *argv, "--steps", "512")
    g = a["gain_chart"]
    assert a["charted_drive"] == "elbow" and a["drives"] == ["shoulder", "elbow"]
    r_n, r_2n = np.array(g["spectral_radius"]), np.array(b["gain_chart"]["spectral_radius"])
    omega = 2 * math.pi
    ref = np.array([[dominant(double_pendulum_multipliers(omega, (5.0, kp), (0.5, kd))) for kp in g["kp"]]
                    for kd in g["kd"]])
    tol = 2 * 4 / 3 * np.abs(r_n - r_2n) + 1e-8
    assert np.all(np.abs(r_n - ref) <= tol), (r_n, ref, tol)
    # the check can fail: the same grid on the shoulder drive (others fixed) is a different chart
    wrong = np.array([[dominant(double_pendulum_multipliers(omega, (kp, 0.0), (kd, 0.0))) for kp in g["kp"]]
                      for kd in g["kd"]])
    assert np.max(np.abs(r_n - wrong) - tol) > 1e-3


@pytest.mark.parametrize("argv, rc, words", [
    (["--kp-range", "5", "1"], 2, "kp-range is empty or inverted"),
    (["--omega-range", "3", "2"], 2, "omega range is empty or inverted"),
    (["--drive", "knee"], 2, "drives are shoulder, elbow"),
    (["--kp", "1,2,3"], 2, "2 drive(s)"),
    (["--scheduler", "tcp://127.0.0.1"], 2, "has no port"),  # checked before the first orbit
])
def test_bad_chart_input_is_one_line(tmp_path, capsys, argv, rc, words):
    code = cli_main(["chart", "--model", DOUBLE, "--grid", "2", "--omega-points", "2", "--no-taguchi",
                     "--out", str(tmp_path), *argv])
    err = capsys.readouterr().err.strip()
    assert code == rc and len(err.splitlines()) == 1 and words in err, err


def test_broken_model_file_is_one_line(tmp_path, capsys):
    f = tmp_path / "broken.py"
    f.write_text("import exudyn\ndef build(mbs, omega):\n    raise RuntimeError('no such body: arm')\n")
    assert cli_main(["chart", "--model", str(f), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no such body: arm" in err, err
    g = tmp_path / "syntax.py"
    g.write_text("def build(mbs, omega)\n    return []\n")
    assert cli_main(["chart", "--model", str(g), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "syntax.py" in err, err


def test_orbit_continued_from_a_nearby_omega_is_the_same_orbit(monkeypatch):
    """``find_orbit(guess=...)`` (the Omega chart's continuation) converges to the orbit found from
    scratch (both to the collocation tolerance, so within ~1e-10 of each other), without simulating
    a period for the guess; a guess of another size falls back to the usual guess."""
    import linearize.periodic_orbit as po

    near = po.find_orbit(DOUBLE, 6.0, samples=32, verify=False)
    fresh = po.find_orbit(DOUBLE, 6.5, samples=32, verify=False)
    simulated = []
    usual = po._guess

    def counting_guess(col, model):
        simulated.append(col.K)
        return usual(col, model)

    monkeypatch.setattr(po, "_guess", counting_guess)
    cont = po.find_orbit(DOUBLE, 6.5, samples=32, verify=False, guess=near)
    assert simulated == []  # Newton started from the given orbit and converged from it
    scale = np.max(np.abs(fresh.q))
    assert np.max(np.abs(cont.q - fresh.q)) <= 1e-9 * scale
    assert np.max(np.abs(cont.torques - fresh.torques)) <= 1e-9 * np.max(np.abs(fresh.torques))
    other = po.find_orbit(DOUBLE, 6.5, samples=16, verify=False, guess=near)  # 32 samples cannot seed 16
    assert simulated == [16] and other.residual <= other.tolerance
