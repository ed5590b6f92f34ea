"""Error estimates that bound the multipliers themselves (moduli and phases) on a small system whose
moduli do not depend on the step: the anisotropic Laval rotor with uniform external damping (every
multiplier has the modulus exp(-c T / 2 m)), against its closed form (tests/_laval_oracle.py)."""
from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("exudyn")

import _laval_oracle as oracle  # noqa: E402  (tests/ helper)

#: the linearisation's own error (Exudyn's numerical Jacobian of the shaft's user function), measured
#: in tests/test_laval_rotor.py: <= 3.5e-9 over 20..250 rad/s; the estimates speak of the propagator only
LINEARISATION = 3.5e-9


def _relative_errors(mu, W):
    ref = oracle.multipliers(W)
    return np.array([np.min(np.abs(ref - x)) / abs(x) for x in np.asarray(mu)])


@pytest.mark.parametrize("frame, method", [("model", "magnus6"), ("modal", "magnus2")])
@pytest.mark.parametrize("W", [30.0, 200.0])
def test_adaptive_estimate_bounds_the_multiplier_error(W, frame, method):
    from linearize import analyze

    res = analyze("laval-rotor", W, frame=frame, method=method, n_steps=None)
    f = res.floquet
    est = 10.0 ** -np.asarray(f.reliable_digits, float)
    err = _relative_errors(f.multipliers, W)
    assert np.all(err <= est + LINEARISATION), (err, est)
    assert f.accuracy == "multipliers"
    assert float(f.error_estimate) < 1e-8  # a bound, not a vacuous one


def test_moduli_alone_see_no_error_here():
    """Why the estimate must cover the phases: the moduli of the rotor are step-independent, so their
    change between levels is rounding while the multipliers are far off (the wrong answer the
    multipliers' estimate rejects)."""
    from linearize import analyze
    from stability import floquet

    lin = analyze("laval-rotor", 30.0).linearization
    coarse = floquet(lin, method="magnus6", n_steps=32, accuracy="moduli")
    ref = oracle.multipliers(30.0)
    moduli_error = max(np.min(np.abs(np.abs(ref) - abs(x))) for x in coarse.multipliers)
    assert moduli_error < 1e-13 < 1e-7 < float(np.max(_relative_errors(coarse.multipliers, 30.0)))


def test_cli_certifies_only_multipliers_within_rtol(capsys):
    from flexstab.cli import main

    main(["floquet", "--model", "laval-rotor", "--omega", "30", "--json"])
    d = json.loads(capsys.readouterr().out)
    mu = np.array([complex(*m) for m in d["multipliers"]])
    err = _relative_errors(mu, 30.0)
    certified = np.asarray(d["certified"], bool)
    assert certified.any()
    assert np.all(err[certified] <= d["rtol"]), (err, d["rtol"])
