"""The verdict on an autonomous orbit (its phase free): orbital stability, the structural multiplier 1 left out.

Oracle: ``tests/models/motor_rotor.py``, a symmetric rigid rotor on symmetric bearings spun by a motor
characteristic ``tau = c (Omega - theta')`` and nothing else depending on time.  The spin-rate
perturbation obeys ``J_x d' = -c d`` exactly (decoupled by the symmetry), so one multiplier is
``exp(-c T / J_x)``; one multiplier is 1 (a time shift of the spin is again an orbit).  The motor damps
every physical mode, so the orbit is orbitally asymptotically stable -- and the rule must still call
``critical`` what is undamped: the free spin of ``turning_rotor_ep.py`` (no motor) conserves its angular
momentum, a second multiplier 1 that is a property of the motion.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from linearize.analysis import analyze
from stability.verdict import VERDICT_CRITICAL, VERDICT_STABLE, judge, judge_floquet

MODELS = Path(__file__).parent / "models"
W = 30.0
JX = 0.01


@pytest.mark.parametrize("slope", [0.004, 0.008])
def test_motor_rotor_spin_multiplier_and_orbital_verdict(slope):
    res = analyze(str(MODELS / "motor_rotor.py"), W, n_steps=None, rtol=1e-10, motor=slope)
    assert res.orbit.autonomous
    mu = np.asarray(res.floquet.multipliers)
    est = max(float(res.floquet.error_estimate), 1e-12)
    exact = math.exp(-slope * (2 * math.pi / W) / JX)
    assert np.min(np.abs(mu - exact)) <= 10 * est * max(1.0, exact)
    # a wrong spin law (c / J_y instead of c / J_x) is rejected by the same check
    assert np.min(np.abs(mu - math.exp(-slope * (2 * math.pi / W) / 0.05))) > 1e3 * est
    (i,) = res.structural
    assert abs(mu[i] - 1.0) <= 10 * est
    v = res.verdict
    assert v.verdict == VERDICT_STABLE and v.structural == (i,) and v.n_multipliers == mu.size - 1
    assert "orbital" in v.message
    # judged with the structural multiplier, the same orbit would be called critical
    assert judge_floquet(res.floquet).verdict == VERDICT_CRITICAL


def test_free_spin_stays_critical_its_momentum_multiplier_is_real():
    res = analyze(str(MODELS / "turning_rotor_ep.py"), W, n_steps=None, node="EP", rtol=1e-10)
    assert res.orbit.autonomous and len(res.structural) == 1
    v = res.verdict
    assert v.verdict == VERDICT_CRITICAL and len(v.undamped) == 1


def test_judge_structural_indices():
    v = judge([1.0, 0.5], [1e-9, 1e-9], structural=[0])
    assert v.verdict == VERDICT_STABLE and v.spectral_radius == 0.5 and v.to_dict()["structural_count"] == 1
    assert judge([1.0, 0.5], [1e-9, 1e-9]).verdict == VERDICT_CRITICAL
    for bad in ([2], [0, 1], [-1]):
        with pytest.raises(ValueError, match="structural"):
            judge([1.0, 0.5], [1e-9, 1e-9], structural=bad)


def test_structural_multiplier_must_be_one_within_its_error():
    """Only a multiplier that is 1 within (ten times) its error estimate is left out as the phase shift of
    an autonomous orbit; otherwise nothing is (no real multiplier may vanish from the verdict)."""
    import types

    from linearize.analysis import ModelFloquetResult

    def structural(mus, digits, autonomous=True):
        ns = types.SimpleNamespace(orbit=types.SimpleNamespace(autonomous=autonomous),
                                   floquet=types.SimpleNamespace(multipliers=np.array(mus, complex),
                                                                 reliable_digits=np.array(digits, float)))
        return ModelFloquetResult.structural.func(ns)

    assert structural([0.5, 1.0 + 1e-9, 0.2], [10, 8, 10]) == (1,)
    assert structural([0.5, 1.0 + 3e-4, 0.2], [10, 4, 10]) == (1,)  # a defective 1: sqrt-level error
    assert structural([0.5, 0.9, 0.2], [10, 10, 10]) == ()
    assert structural([0.5, 1.0 + 1e-9], [10, 8], autonomous=False) == ()


def test_cli_marks_the_structural_row_and_states_the_judged_radius(capsys):
    """The table of an autonomous orbit marks the structural multiplier's row and prints, beside the
    spectral radius 1, the radius the verdict judged (the JSON's verdict_detail); a forced model marks none."""
    import json

    from flexstab.cli import main

    model = str(Path(__file__).with_name("models") / "motor_rotor.py")
    assert main(["floquet", "--model", model, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["structural_multipliers"] == 1 and len(d["structural_indices"]) == 1
    i = d["structural_indices"][0]
    assert abs(complex(*d["multipliers"][i]) - 1.0) < 1e-6
    assert main(["floquet", "--model", model]) == 0
    out = capsys.readouterr().out
    row = [line for line in out.splitlines() if line.strip().startswith(f"{i + 1} ")][0]
    assert "structural" in row
    judged = d["verdict_detail"]["spectral_radius"]
    assert judged < 0.9 and f"judged without the structural multiplier: {judged:.10g}" in out
