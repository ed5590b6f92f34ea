"""Transient responses (paper Figs. 2-9): ``stability.response`` and ``scripts/transients.py``.

Oracles, none of them the code's own earlier output:

* constant-coefficient systems: ``x(t) = expm(A t) x0`` and, with a constant
  forcing ``f``, ``x(t) = expm(A t) x0 + A^-1 (expm(A t) - I) f``;
* a synthetic envelope ``a sin(2 pi t / T) rho^(t/T)`` whose constant is ``a``;
* the Floquet multipliers of the reduced model (6th-order Magnus, a different
  discretisation from the Radau/DOP853 time integration): for a simple, real
  dominant multiplier, ``||x((k+1)T)|| / ||x(kT)||`` tends to ``|rho_1|``
  (power method).
"""
from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from mbs_models.reduced import ReducedModel
from stability import floquet
from stability.response import (
    DEFAULT_RTOL,
    LinearResponse,
    choose_method,
    envelope_constant,
    linear_response,
    per_period_growth,
)

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "transients.py"

#: A lightly damped 2-DOF oscillator in first-order form (eigenvalues
#: about -0.05 +- 1.0i and -0.2 +- 3.1i), plus a stiff variant.
A_OSC = np.array(
    [
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
        [-2.0, 1.0, -0.1, 0.0],
        [1.0, -9.0, 0.0, -0.4],
    ]
)
A_STIFF = A_OSC.copy()
A_STIFF[2, 2] = -2000.0


def _load_script():
    name = "flexstab_scripts_transients"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the file executes
    spec.loader.exec_module(module)
    return module


# --------------------------------------------------------------------------- analytic systems
@pytest.mark.parametrize("A, method", [(A_OSC, "DOP853"), (A_OSC, "Radau"), (A_STIFF, "Radau")])
def test_constant_system_matches_matrix_exponential(A, method):
    x0 = np.array([0.0, 0.0, 0.25 * math.pi, 0.0])
    r = linear_response(lambda t: A, x0, 6.0, period=1.5, n_per_period=50, method=method)
    idx = np.arange(0, len(r.t), 7)  # scipy's expm costs ~5 ms a call: check a subset
    exact = np.array([expm(A * t) @ x0 for t in r.t[idx]])
    # error normalised by the requested tolerance (scipy's convention); the
    # global error of a tolerance-controlled integrator may exceed it by a
    # modest factor.
    err = np.max(np.abs(r.x[idx] - exact)) / (DEFAULT_RTOL * np.max(np.abs(exact)))
    assert err < 100.0, err
    assert r.method == method and r.homogeneous


def test_constant_forcing_matches_closed_form():
    x0 = np.array([0.1, -0.2, 0.0, 0.3])
    f = np.array([0.0, 0.0, 1.0, -0.5])
    r = linear_response(lambda t: A_OSC, x0, 5.0, forcing=lambda t: f, period=1.0, n_per_period=20)
    Ainv_f = np.linalg.solve(A_OSC, f)
    idx = np.arange(0, len(r.t), 5)
    exact = np.array([expm(A_OSC * t) @ (x0 + Ainv_f) - Ainv_f for t in r.t[idx]])
    err = np.max(np.abs(r.x[idx] - exact)) / (DEFAULT_RTOL * np.max(np.abs(exact)))
    assert err < 100.0, err
    assert not r.homogeneous


def test_grid_contains_every_period_exactly_and_is_frozen():
    T = 0.3
    r = linear_response(lambda t: -np.eye(2), [1.0, 2.0], 7 * T + 0.05, period=T, n_per_period=16)
    assert r.n_full_periods == 7
    np.testing.assert_array_equal(r.t[r.period_indices()], T * np.arange(8))
    assert r.t[-1] == pytest.approx(7 * T + 0.05)
    # tolerance-controlled global error <= 100 DEFAULT_RTOL (as in the analytic tests above)
    np.testing.assert_allclose(r.at_periods()[:, 0], np.exp(-T * np.arange(8)), rtol=100 * DEFAULT_RTOL)
    with pytest.raises(Exception):
        r.t = None  # frozen dataclass


def test_per_period_growth_of_scalar_exponential():
    # x' = a x: every per-period ratio is exp(a T) exactly.
    a, T = 0.7, 0.5
    r = linear_response(lambda t: np.array([[a]]), [1.0], 6 * T, period=T, n_per_period=10)
    g = per_period_growth(r, skip=0)
    # a ratio of two samples, each within 100 DEFAULT_RTOL (global error of the integrator)
    tol = 2 * 100 * DEFAULT_RTOL
    np.testing.assert_allclose(g.ratios, math.exp(a * T), rtol=tol)
    np.testing.assert_allclose(g.peak_ratios, math.exp(a * T), rtol=tol)
    assert g.fitted == pytest.approx(math.exp(a * T), rel=tol)


def test_envelope_constant_recovers_amplitude():
    T, rho, a = 0.25, 0.4, 3e-3
    t = np.linspace(0.0, 5 * T, 5 * 400 + 1)
    y = a * np.sin(2 * math.pi * t / T) * rho ** (t / T)
    # max |y| rho^(-t/T) = a |sin|: its peak t = T/4 + 4T lies on the grid (400 per period), so only
    # rounding of sin and of rho^(t/T) remains (~1e-15); 1e-5 would also cover a grid offset up to 7e-4 T
    assert envelope_constant(t, y, rho, T, t_from=4 * T) == pytest.approx(a, rel=1e-5)


def test_choose_method_stiffness_rule():
    assert choose_method(lambda t: A_OSC, 1.0) == "DOP853"
    assert choose_method(lambda t: A_STIFF, 1.0) == "Radau"
    # the PD-controlled manipulator at Omega = 2 pi has a real eigenvalue near -3200/s
    assert choose_method(ReducedModel(2 * math.pi, 37.1617, 29.2410), 1.0) == "Radau"
    assert choose_method(ReducedModel(2 * math.pi), 1.0) == "DOP853"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(x0=[1.0, 0.0], t_end=0.0, period=1.0), "t_end"),
        (dict(x0=[1.0, 0.0], t_end=math.inf, period=1.0), "t_end"),
        (dict(x0=[1.0, 0.0, 0.0], t_end=1.0, period=1.0), "shape"),
        (dict(x0=[math.nan, 0.0], t_end=1.0, period=1.0), "NaN"),
        (dict(x0=[1.0, 0.0], t_end=1.0), "period"),
        (dict(x0=[1.0, 0.0], t_end=1.0, period=-1.0), "period"),
        (dict(x0=[1.0, 0.0], t_end=1.0, period=1.0, n_per_period=1), "n_per_period"),
    ],
)
def test_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        linear_response(lambda t: -np.eye(2), **kwargs)


# --------------------------------------------------------------------------- the manipulator
def test_controlled_growth_matches_floquet_multiplier():
    """Table 3, Omega = 2 pi: ||x((k+1)T)|| / ||x(kT)|| -> rho_1 (Magnus Floquet, independent)."""
    model = ReducedModel(2 * math.pi, 37.1617, 29.2410)
    fl = floquet(model)
    rho1 = fl.multipliers[0]
    assert abs(rho1.imag) == 0.0 and rho1.real > 0  # real, simple, dominant
    r = linear_response(model, [0.0, 0.0, 0.25 * math.pi, 0.0], 4 * model.period, n_per_period=50)
    g = per_period_growth(r, skip=1)
    np.testing.assert_allclose(g.ratios[1:], fl.spectral_radius, rtol=1e-3)
    # and componentwise: x((k+1)T) = rho_1 x(kT) once the other solutions are gone
    xs = r.at_periods()
    np.testing.assert_allclose(xs[3], rho1.real * xs[2], rtol=1e-3, atol=1e-6 * np.max(np.abs(xs[2])))


@pytest.mark.slow
def test_script_quick_writes_figures_and_json(tmp_path):
    script = _load_script()
    assert script.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "transients.json").read_text())
    assert doc["quick"] and not doc["figures_include_forcing"]
    from flexstab.transients import QUICK_FIGURES

    assert [c["figure"] for c in doc["cases"]] == list(QUICK_FIGURES)
    for case in doc["cases"]:
        png = tmp_path / case["figure_file"]
        assert png.is_file() and png.stat().st_size > 20_000
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        for key in ("dominant_multiplier", "spectral_radius", "ratios_state_norm", "last_ratio", "fitted_ratio"):
            assert key in case
    controlled = [c for c in doc["cases"] if c["controlled"]]
    assert controlled
    for case in controlled:
        # rho_1 recomputed with another Floquet scheme (4th-order Magnus; the
        # 'paper' Radau method agrees too but costs ~14 s here)
        model = ReducedModel(case["omega"], case["kp"], case["kd"])
        rho = floquet(model, method="magnus4").spectral_radius
        assert case["spectral_radius"] == pytest.approx(rho, rel=1e-6)
        # measured growth of the time response (a different computation) beside it
        assert case["last_ratio"] == pytest.approx(rho, rel=0.02)
        assert case["fitted_ratio"] == pytest.approx(rho, rel=0.05)
        assert case["spectral_radius"] == pytest.approx(case["printed_spectral_radius"], rel=1e-3)


@pytest.mark.slow
def test_caption_matches_the_plotted_periods_and_quotes_no_rounding_noise():
    """Captions name plotted vs integrated periods; rho2 below the floor is a bound."""
    from flexstab.transients import QUICK, _caption, paper_case_pair, run_case

    unc, ctl = paper_case_pair(2)
    r = run_case(ctl, QUICK, False)
    s = r["summary"]
    assert not s["subdominant_reliable"]  # |rho2| ~ 1e-19 here: below n eps ||Phi||
    cap = _caption(ctl, r, False)
    assert "below the rounding floor" in cap and f"{s['subdominant_over_dominant']:.3g}" not in cap
    r = run_case(unc, QUICK, False)
    cap = _caption(unc, r, False)
    s = r["summary"]
    assert s["periods_measured"] > s["periods_plotted"]
    assert f"the first {s['periods_plotted']} are plotted" in cap and "integrated beyond" in cap
    assert f"|ρ₂/ρ₁| = {s['subdominant_over_dominant']:.3g}" in cap
