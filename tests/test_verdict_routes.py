"""One physical model, one verdict: the single link with the paper's Table 3 gains through every route.

Routes: the test suite's oracle (:func:`_link_oracle.link_floquet.exudyn_floquet`: hand-derived hub-frame
coordinates, its own orbit and finite-difference linearisation) and ``--model single-link`` (which
``--model exudyn`` is)
(:func:`linearize.analysis.analyze` on the built-in model file: generic constrained linearisation).
They share no orbit, no linearisation and no coordinates, so their agreement is a cross-check of
two independent linearisations of the same Exudyn link.  Bound on the spectral radii: the hand
route's orbit residual is 6e-7 (relative) and its linearisation is a central difference of it,
so the two linearisations may differ by ~1e-6; the propagation errors are far below (estimates
< 3e-8 at 512 frozen-modal steps).  The wrong answer each test rejects: the hand route propagated
in its own coordinates (``frame="model"``, 512 steps), whose midpoint product sits on a step-size
resonance of the axial modes at 8 pi (spectral radius 1.0022 instead of 0.99996).
"""
from __future__ import annotations

import math

import pytest

from linearize.analysis import analyze
from _link_oracle.link_floquet import exudyn_floquet
from mbs_models.paper_data import TABLE3_GAINS
from mbs_models.parameters import ManipulatorParameters
from stability.verdict import VERDICT_CRITICAL, VERDICT_STABLE

pytestmark = pytest.mark.slow

#: Spectral radii of the two routes agree within this (module notes: the linearisations' difference).
ROUTE_BOUND = 2e-6


def _routes(k: int, elements: int = 8, material: float = 0.0):
    """Both routes at Omega = k pi; ``material``: Kelvin-Voigt loss time (s), written into each route's
    ANCF elements by hand here (beta EI, beta EA) and through the built-in's ``material_damping``."""
    kp, kd = TABLE3_GAINS[k]
    omega = k * math.pi
    p = ManipulatorParameters()
    ex = exudyn_floquet(p, omega=omega, kp=kp, kd=kd, elements=elements,
                        bending_damping=material * p.bending_stiffness, axial_damping=material * p.axial_stiffness)
    opts = {"material_damping": material} if material else {}
    fl = analyze("single-link", omega, kp=kp, kd=kd, elements=elements, params=p, **opts)
    return ex, fl


@pytest.fixture(scope="module")
def eight_pi():
    return _routes(8)


def test_eight_pi_same_verdict_through_both_routes(eight_pi):
    ex, fl = eight_pi
    a, b = ex.verdict, fl.verdict
    assert a.verdict == b.verdict == VERDICT_CRITICAL
    assert abs(a.spectral_radius - b.spectral_radius) <= ROUTE_BOUND
    assert a.spectral_radius_label == b.spectral_radius_label
    assert len(a.undamped) == len(b.undamped) > 0
    # the paper's response (hub) agrees as well, and is far inside: only the undamped mesh modes are critical
    assert abs(abs(ex.dominant_multiplier) - abs(fl.dominant_multiplier)) <= ROUTE_BOUND
    assert abs(fl.dominant_multiplier) < 0.5


def test_eight_pi_hub_frame_product_is_rejected(eight_pi):
    ex, fl = eight_pi
    wrong = exudyn_floquet(omega=8 * math.pi, kp=TABLE3_GAINS[8][0], kd=TABLE3_GAINS[8][1], elements=8,
                           orbit=ex.orbit, frame="model")
    # the step-size resonance: 1.0022 (axial 6) -- outside the bound of the cross-check by three decades
    assert abs(wrong.floquet.spectral_radius - fl.verdict.spectral_radius) > 1000 * ROUTE_BOUND
    assert wrong.floquet.spectral_radius > 1.0


@pytest.mark.parametrize("elements", [8, 16])
def test_two_pi_critical_at_every_converged_mesh(elements):
    kp, kd = TABLE3_GAINS[2]
    fl = analyze("single-link", 2 * math.pi, kp=kp, kd=kd, elements=elements, params=ManipulatorParameters())
    v = fl.verdict
    # converged: the spectral radius' own estimate is far below its distance from the threshold
    assert v.spectral_radius_error < 1e-3 * (v.spectral_radius - v.threshold)
    assert v.verdict == VERDICT_CRITICAL
    # every practically undamped multiplier is a structural mesh mode, not the hub
    assert "hub" not in v.undamped_labels and len(v.undamped) >= 2 * elements
    # the former rule (rho < 1 - 1e-8) called this asymptotically stable: rejected here
    assert v.spectral_radius < 1.0 - 1e-8 and v.verdict != VERDICT_STABLE
    if elements == 8:
        ex = exudyn_floquet(omega=2 * math.pi, kp=kp, kd=kd, elements=8)
        assert ex.verdict.verdict == VERDICT_CRITICAL
        assert abs(ex.verdict.spectral_radius - v.spectral_radius) <= ROUTE_BOUND


def test_structural_damping_makes_it_asymptotically_stable():
    beta = 1e-5  # s: Kelvin-Voigt loss time, zeta ~ 1e-3 at 30 Hz
    ex, fl = _routes(2, material=beta)
    for v in (ex.verdict, fl.verdict):
        assert v.verdict == VERDICT_STABLE
        assert v.margin > 0.5  # the hub (|rho| = 0.2998) is now the slowest mode
        assert v.spectral_radius_label == "hub"
        assert "decays by e in" in v.message
    assert abs(ex.verdict.spectral_radius - fl.verdict.spectral_radius) <= ROUTE_BOUND
    # and without damping the same model is critical (the verdict is decided by the damping)
    kp, kd = TABLE3_GAINS[2]
    undamped = analyze("single-link", 2 * math.pi, kp=kp, kd=kd, elements=8, params=ManipulatorParameters())
    assert undamped.verdict.verdict == VERDICT_CRITICAL
