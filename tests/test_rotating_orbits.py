"""Orbits periodic up to whole turns: a hinged blade on a hub turning at constant speed.

Oracle: the hand-derived equations of ``tests/_blade_reference.py`` (Lagrange's equations of hub and
blade; the blade's variational equation written out), integrated by scipy's DOP853 at rtol 1e-12.
The package solves the same model written in Exudyn's idiom (``tests/models/hinged_blade.py``) once
with a drive ``motion = (Omega t, Omega, 0)`` and once with a ``CoordinateConstraint`` whose offset
is ``Omega t``.  Each comparison is paired with a wrong reference it must reject.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest

import _blade_reference as ref
from linearize.analysis import analyze
from linearize.periodic_orbit import OrbitConvergenceError, find_orbit
from mbs_models.model_file import ModelFileError

MODEL = str(Path(__file__).with_name("models") / "hinged_blade.py")
OMEGA = 6.0
#: the adaptive frozen-modal Floquet solve meets rtol 1e-9 (its default); the 32-sample orbit of this
#: smooth 1-2 dof model is exact to ~1e-12 (its Fourier coefficients decay geometrically): 1e-8 bounds both
TOLERANCE = 1e-8


def _distance(a, b) -> float:
    """Largest distance of two multiplier sets, matched greedily (sets of equal size)."""
    a, b = list(np.asarray(a, dtype=complex)), list(np.asarray(b, dtype=complex))
    worst = 0.0
    for x in a:
        j = int(np.argmin([abs(x - y) for y in b]))
        worst = max(worst, abs(x - b.pop(j)))
    return worst


def test_constraint_form_matches_the_hand_derived_blade_equation():
    """Hub held by a rheonomic ``CoordinateConstraint`` (offset Omega t): the one independent
    coordinate is the blade angle; multipliers = the hand-derived variational equation's."""
    tic = time.process_time()
    res = analyze(MODEL, OMEGA, form="constraint", n_steps=None)
    cpu = time.process_time() - tic
    expected = ref.blade_multipliers(OMEGA)
    assert res.linearization.size == 1
    assert _distance(res.floquet.multipliers, expected) <= TOLERANCE
    # the orbit turns: hub and blade advance by one turn per period, the rest is periodic
    turns = np.round(res.orbit.shift / (2 * math.pi)).astype(int)
    assert sorted(turns.tolist()) == [0, 0, 0, 0, 1, 1]
    # rejects a wrong answer: the centrifugal term with the wrong sign
    wrong = ref.blade_multipliers(OMEGA, centrifugal_sign=-1.0)
    assert _distance(res.floquet.multipliers, wrong) > 1e3 * TOLERANCE
    assert cpu < 30.0


@pytest.mark.parametrize("kp, kd", [(0.0, 0.0), (5.0, 0.5)])
def test_drive_form_matches_the_hand_derived_hub_and_blade(kp, kd):
    """Drive ``(Omega t, Omega, 0)`` released under feed-forward + PD: two independent coordinates
    (hub, blade); multipliers = the hand-derived 2-dof variational equation's."""
    res = analyze(MODEL, OMEGA, kp=kp, kd=kd, n_steps=None)
    expected = ref.hub_blade_multipliers(OMEGA, kp, kd)
    assert res.linearization.size == 2
    assert _distance(res.floquet.multipliers, expected) <= TOLERANCE
    # rejects a wrong answer: the orbit with two turns per period instead of one
    assert _distance(res.floquet.multipliers, ref.hub_blade_multipliers(OMEGA, kp, kd, turns=2)) > 1e3 * TOLERANCE


def test_two_turns_per_period_is_an_orbit_too_and_differs_from_one():
    """``turns=2``: the hub turns twice per period; matches the hand reference about ``theta = 2 Omega t``
    and not the one about ``Omega t`` (a wrong k)."""
    res = analyze(MODEL, OMEGA, kp=5.0, kd=0.5, turns=2, n_steps=None)
    assert np.round(res.orbit.shift[2] / (2 * math.pi)) == 2
    assert _distance(res.floquet.multipliers, ref.hub_blade_multipliers(OMEGA, 5.0, 0.5, turns=2)) <= TOLERANCE
    assert _distance(res.floquet.multipliers, ref.hub_blade_multipliers(OMEGA, 5.0, 0.5, turns=1)) > 1e3 * TOLERANCE


def test_orbit_state_carries_the_turns():
    """``PeriodicOrbit.state(t)`` continues the turns (``q(t + T) = q(t) + shift``) and ``q_t`` is
    the spectral rate of the whole motion (the hub turns at Omega)."""
    orbit = find_orbit(MODEL, OMEGA, verify=True)
    T = orbit.period
    q_a, _, _ = orbit.state(0.3 * T)
    q_b, _, _ = orbit.state(1.3 * T)
    assert np.max(np.abs(q_b - q_a - orbit.shift)) <= 1e-12 * 2 * math.pi
    hub = int(np.flatnonzero(orbit.drive_vectors[:, 0])[0])
    assert np.max(np.abs(orbit.q_t[:, hub] - OMEGA)) <= 1e-9 * OMEGA
    assert np.max(np.abs(orbit.q[:, hub] - OMEGA * orbit.times)) <= 1e-9
    assert orbit.shooting_residual <= 1e-2


def test_a_fraction_of_a_turn_per_period_is_rejected_as_input():
    """A drive advancing by 1.5 turns per period is not periodic up to whole turns: exit-2 error at build."""
    with pytest.raises(ModelFileError, match="not T-periodic, nor periodic up to whole turns"):
        find_orbit(MODEL, OMEGA, turns=1.5)


def test_a_growing_coordinate_is_told_within_seconds():
    """A rheonomic constraint advancing 1.5 turns per period: no orbit exists.  The failure names the
    growing coordinate and comes without the continuation in omega (seconds, not minutes)."""
    tic = time.perf_counter()
    with pytest.raises(OrbitConvergenceError) as err:
        find_orbit(MODEL, OMEGA, form="constraint", turns=1.5)
    wall = time.perf_counter() - tic
    msg = str(err.value)
    assert "hub[2] advances by 9.425" in msg and "1.5 turns" in msg and "neither periodic nor" in msg
    assert "continuation" not in msg and len(msg.splitlines()) == 1
    assert wall < 20.0  # measured ~2 s on a loaded machine; the continuation took 70 s


def _cli_json(capsys, argv):
    import json

    from flexstab.cli import main

    rc = main(argv)
    out = capsys.readouterr().out
    return rc, json.loads(out)


@pytest.mark.slow
def test_tune_and_validate_on_the_released_hub_agree_with_the_hand_reference(capsys, tmp_path):
    """``flexstab tune`` on the drive form reaches rho_d = 0.3 as the hand-derived 2-dof variational
    equation measures it at the tuned gains; ``flexstab validate`` at those gains measures (nonlinear
    Exudyn closed loop) multipliers within its error bar of the hand reference, and the hand reference
    with two turns per period (a wrong k) lies outside that bar."""
    target = 0.3
    rc, tuned = _cli_json(capsys, ["tune", "--model", MODEL, "--omega", str(OMEGA), "--target", str(target),
                                   "--kp-range", "0", "20", "--kd-range", "0", "2", "--json"])
    assert rc == 0 and tuned["converged"]
    kp, kd = (float(np.atleast_1d(tuned[k])[0]) for k in ("kp", "kd"))  # one drive: a number or a one-item list
    rho_ref = float(np.max(np.abs(ref.hub_blade_multipliers(OMEGA, kp, kd))))
    # the tuning tolerance plus the tuning propagator's error (its estimate, a few 1e-5 here)
    assert abs(rho_ref - target) <= tuned["tolerance"] + 1e-4
    rc, val = _cli_json(capsys, ["validate", "--model", MODEL, "--omega", str(OMEGA), "--kp", str(kp),
                                 "--kd", str(kd), "--json", "--out", str(tmp_path)])
    assert rc == 0 and val["agrees"]
    expected = ref.hub_blade_multipliers(OMEGA, kp, kd)
    wrong = ref.hub_blade_multipliers(OMEGA, kp, kd, turns=2)
    for m in val["multipliers"]:
        mu = complex(*m["measured"])
        assert min(abs(mu - e) for e in expected) <= m["error_bar"]
        assert min(abs(mu - e) for e in wrong) > 10 * m["error_bar"]


def _rotor_reference(omega, kp, kd, gyroscopic=1.0):
    """Multipliers ``exp(lambda T)`` of the rigid rotor's constant-coefficient linearisation in a frame fixed
    in space (hand-derived: translations, spin under PD, tilts with the gyroscopic coupling J_p Omega)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("rigid_rotor_constants",
                                                  Path(MODEL).with_name("rigid_rotor_rxyz.py"))
    rr = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rr)
    m, Jp, Jt, a, k, kx, c = rr.MASS, rr.J_POLAR, rr.J_TRANSVERSE, rr.A, rr.K, rr.KX, rr.C
    blocks = [np.array([[0.0, 1.0], [-2 * kk / m, -2 * c / m]]) for kk in (kx, k, k)]
    blocks.append(np.array([[0.0, 1.0], [-kp / Jp, -kd / Jp]]))
    G = gyroscopic * Jp * omega
    tilt = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-2 * k * a * a / Jt, 0, -2 * c * a * a / Jt, -G / Jt],
                     [0, -2 * k * a * a / Jt, G / Jt, -2 * c * a * a / Jt]])
    lam = np.concatenate([np.linalg.eigvals(b) for b in blocks] + [np.linalg.eigvals(tilt)])
    return np.exp(lam * 2 * math.pi / omega)


@pytest.mark.parametrize("omega", [30.0, 80.0])
def test_rxyz_rotor_spinning_whole_turns_matches_the_constant_coefficient_oracle(omega):
    """A 3D rotor whose Tait-Bryan spin angle is a drive ``(Omega t, Omega, 0)``: its multipliers are
    ``exp(lambda T)`` of the fixed-frame constant-coefficient system (to 1e-8); without the gyroscopic
    term (a wrong answer) they are not."""
    rotor = str(Path(MODEL).with_name("rigid_rotor_rxyz.py"))
    res = analyze(rotor, omega, kp=5.0, kd=0.5, n_steps=None)
    assert np.round(res.orbit.shift / (2 * math.pi)).astype(int).tolist() == [0, 0, 0, 1, 0, 0]
    assert _distance(res.floquet.multipliers, _rotor_reference(omega, 5.0, 0.5)) <= TOLERANCE
    assert _distance(res.floquet.multipliers, _rotor_reference(omega, 5.0, 0.5, gyroscopic=0.0)) > 1e-2


@pytest.mark.parametrize("held", [False, True])
def test_turning_rotation_vector_node_off_its_principal_axes_matches_the_constant_coefficient_oracle(held):
    """A rotor with a rotation-vector node whose own frame is turned against its principal axes (reference
    rotation vector (0.4, -0.7, 0.9): the spin axis is no axis of the node's frame), spinning one turn per
    period -- freely (autonomous: the spin's pair at 1 is structural) or held at omega t by a rheonomic joint.
    The node is presented in a Tait-Bryan chart about the spin axis (one turn of its first angle) and the
    multipliers are the hand-derived constant-coefficient ones (to 1e-8); without the gyroscopic term (a wrong
    answer) they are not."""
    res = analyze(str(Path(MODEL).with_name("turning_rotor_ep.py")), 30.0, n_steps=None, node="RV", held=held,
                  body_frame=(0.4, -0.7, 0.9), rtol=1e-10)
    assert res.orbit.summary()["turns"] == {"rotor[3]": 1} and res.orbit.autonomous is not held
    mu = np.asarray(res.floquet.multipliers)
    spin = np.abs(mu - 1.0) < 1e-4
    assert int(np.sum(spin)) == (0 if held else 2)
    ref, wrong = _rotor_reference(30.0, 0.0, 0.0), _rotor_reference(30.0, 0.0, 0.0, gyroscopic=0.0)
    ref, wrong = ref[np.abs(ref - 1.0) > 1e-4], wrong[np.abs(wrong - 1.0) > 1e-4]
    assert _distance(mu[~spin], ref) <= TOLERANCE
    assert _distance(mu[~spin], wrong) > 1e-2


def test_a_model_that_changes_after_a_turn_is_refused(tmp_path):
    """A torsion spring from the ground to the turning hub angle: the forces after a whole turn differ,
    so the turn is no symmetry of the model: refused by the invariance check (one line)."""
    src = Path(MODEL).read_text().replace(
        "    if form == \"constraint\":",
        "    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[mg, mh[2]], stiffness=0.5))\n"
        "    if form == \"constraint\":")
    bad = tmp_path / "blade_with_ground_spring.py"
    bad.write_text(src)
    with pytest.raises(ModelFileError, match="not the same after those turns") as err:
        find_orbit(str(bad), OMEGA, form="constraint")
    assert len(str(err.value).splitlines()) == 1


@pytest.mark.slow
def test_an_orbit_at_an_intermediate_continuation_omega_is_never_reported_as_best(monkeypatch):
    """When Newton fails at omega, the message's "best" is the best residual *at omega*; an orbit that
    converged at a lower continuation omega is reported as that, not as a residual of 1e-16."""
    import linearize.periodic_orbit as po

    real = po._newton

    def failing_at_target(col, X, tol, max_iterations, early_give_up=False, second_guess=None, abandoned=None):
        Xn, hist, ok, tb = real(col, X, tol, max_iterations, early_give_up, second_guess)
        if abs(col.built.omega - OMEGA) < 1e-12:  # fail at omega itself, after real iterations
            return Xn, [1e-2 + h for h in hist], False, tb
        return Xn, hist, ok, tb

    monkeypatch.setattr(po, "_newton", failing_at_target)
    monkeypatch.setattr(po, "_growing_coordinates", lambda col: "")
    with pytest.raises(OrbitConvergenceError) as err:
        find_orbit(MODEL, OMEGA, form="constraint")
    msg = str(err.value)
    best = float(msg.split("best at this omega ")[1].split(",")[0])
    assert best >= 1e-2  # every residual at omega was >= 1e-2; the converged lower-omega ones are not "best"
    assert "converged up to" in msg and "omega only" in msg
    assert min(err.value.residuals) < 1e-6  # the history does hold the lower-omega convergence
