"""Newton strategy of the generic periodic orbit (linearize.periodic_orbit) at high Omega.

Oracles: the orbit's own checked residual (never loosened), the one-period
shooting check in Exudyn's integrator (independent of the collocation) and the
hand-derived hub-frame route (``_link_oracle.link_orbit``, independent code and
coordinates).  Each strategy is also shown to matter: with it switched off the
same call ends in :class:`OrbitConvergenceError`, so the tests reject the old
behaviour (damped Newton alone from the simulated period, which needed a long
continuation in omega at 6 pi and 8 pi).
"""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from linearize import periodic_orbit as po
from linearize.periodic_orbit import OrbitConvergenceError, find_orbit

ELEMENTS = 2


def _no_quasi_static(col):  # noqa: ARG001 - same signature as po._quasi_static_guess
    return None


@pytest.mark.parametrize("k", [6, 8])
def test_high_omega_converges_from_the_simulated_guess_without_continuation(k):
    """Full-step Newton from one simulated period reaches the default tolerance at 6 pi and 8 pi
    (32 samples, no continuation, no quasi-static fallback), and Exudyn's integrator confirms it."""
    orbit = find_orbit("single-link", k * math.pi, samples=32, elements=ELEMENTS, continuation=False, verify=True,
                       solver="dense")
    assert orbit.tolerance == po.DEFAULT_TOLERANCE
    assert orbit.residual <= orbit.tolerance
    assert orbit.shooting_residual <= po.SHOOTING_TOLERANCE
    assert orbit.iterations <= po.FULL_STEP_ITERATIONS + po.POLISH_STEPS
    assert set(orbit.cpu_timings) == {"build", "guess", "newton", "tangent", "shooting"}


def test_damped_newton_alone_fails_where_full_steps_converge(monkeypatch):
    """The damped Newton (natural monotonicity test) from the same guess does not converge at 6 pi:
    its rejected first steps are what full steps fix, so the test above rejects the old strategy."""
    monkeypatch.setattr(po, "FULL_STEP_ITERATIONS", 0)
    monkeypatch.setattr(po, "_quasi_static_guess", _no_quasi_static)
    with pytest.raises(OrbitConvergenceError, match="did not converge") as err:
        find_orbit("single-link", 6 * math.pi, samples=32, elements=ELEMENTS, continuation=False, verify=False,
                   solver="dense", max_iterations=12)
    assert min(err.value.residuals) > po.DEFAULT_TOLERANCE
    assert len(str(err.value).splitlines()) == 1 and "best" in str(err.value)


def test_quasi_static_guess_rescues_where_the_simulated_period_fails(monkeypatch):
    """2 elements, 16 samples, 6 pi: full steps from the simulated period do not converge, from the
    quasi-static guess they do; the orbit is the hand-derived route's (not another periodic solution).

    Tolerance of the comparison with the hand route at the same 16 samples: the two
    collocations use different coordinates (absolute vs. hub frame) and so have different
    truncation errors; the generic one is measured 2.4e-5 of the largest torque against its
    own 32-sample orbit (which equals the hand route to 1e-6 in test_model_file), the hand
    one 1.4e-7.  A different periodic orbit differs at O(1); 1e-3 leaves a factor 40.
    """
    from _link_oracle.link_orbit import find_periodic_orbit
    from _link_oracle.exudyn_link import ExudynLinkConfig

    omega = 6 * math.pi
    opts = dict(samples=16, elements=ELEMENTS, continuation=False, solver="dense")
    orbit = find_orbit("single-link", omega, verify=True, **opts)
    assert orbit.residual <= orbit.tolerance == po.DEFAULT_TOLERANCE
    assert orbit.shooting_residual <= po.SHOOTING_TOLERANCE
    hand = find_periodic_orbit(None, ExudynLinkConfig(elements=ELEMENTS, drive="free", omega=omega), samples=16,
                               verify=False)
    scale = float(np.max(np.abs(hand.hub_torques)))
    assert float(np.max(np.abs(orbit.torques[:, 0] - hand.hub_torques))) <= 1e-3 * scale
    # the hub angle follows the drive at every sample (the orbit is on the prescribed motion)
    b = orbit.drive_vectors[:, 0]
    reference = np.array([0.5 * math.pi * (1.0 + math.sin(omega * t)) for t in orbit.times])
    assert np.max(np.abs(orbit.q @ b - reference)) <= 1e-9
    # without the quasi-static guess the same call fails: the fallback is what converged
    monkeypatch.setattr(po, "_quasi_static_guess", _no_quasi_static)
    with pytest.raises(OrbitConvergenceError, match="did not converge"):
        find_orbit("single-link", omega, verify=False, max_iterations=6, **opts)


def test_quasi_static_guess_is_in_equilibrium_on_the_drive():
    """Each sample of the quasi-static guess satisfies the static equations it claims to:
    ``-f(q, 0, t) + C_q^T lambda - B tau = 0``, ``C = 0``, ``B^T q = r(t)`` (checked with Exudyn's
    functions directly, relative to the gravity / elastic force scale)."""
    from mbs_models.model_file import build_model, resolve_model

    omega = 4 * math.pi
    col = po._Collocation(build_model(resolve_model("single-link", elements=ELEMENTS), omega), 8, "dense")
    X = po._quasi_static_guess(col)
    assert X is not None
    Q, L, U = col.split(X)
    zero = np.zeros(col.n)
    for k, t in enumerate(col.times):
        f = col.system.rhs(Q[k], zero, float(t))
        r = -f + col.system.constraint_jacobian(Q[k], float(t)).T @ L[k] - col.B @ U[k]
        # factor 1: _static_solve returns a sample only after this residual (same formula, same point,
        # relative to max |f|) passed QUASI_STATIC_TOLERANCE (measured: 0.1 of the bound)
        assert np.max(np.abs(r)) <= po.QUASI_STATIC_TOLERANCE * np.max(np.abs(f))
        assert np.max(np.abs(col.system.constraints(Q[k], float(t)))) <= 1e-9
        assert abs(float(col.B[:, 0] @ Q[k]) - col.R[k, 0]) <= 1e-9
    # the hub torque holds the link against gravity: tau = -m g x_c cos(angle) summed over the link
    # (statics: the torque balances gravity about O), a number independent of Exudyn
    from mbs_models.parameters import ManipulatorParameters

    p = ManipulatorParameters()
    angle = col.R[:, 0]
    moment = p.gravity * (p.mass_per_length * p.length ** 2 / 2 + p.tip_mass * p.length) * np.cos(angle)
    # the static deflection moves each mass element by at most the Euler-Bernoulli cantilever tip
    # deflection w = q L^4 / (8 EI) + P L^3 / (3 EI) (q, P: gravity load per length and at the tip), so the
    # gravity moment changes by at most g (m_link + m_tip) w: relative bound 2.4e-3 here (measured 4.3e-4)
    EI, m_link = p.youngs_modulus * p.second_moment, p.mass_per_length * p.length
    w = (p.mass_per_length * p.gravity * p.length ** 4 / (8 * EI)
         + p.tip_mass * p.gravity * p.length ** 3 / (3 * EI))
    np.testing.assert_allclose(U[:, 0], moment, rtol=0, atol=p.gravity * (m_link + p.tip_mass) * w)


def _two_link_state():
    from linearize.exudyn_system import ExudynSystem
    from mbs_models.model_file import build_model, resolve_model

    system = ExudynSystem(build_model(resolve_model("two-link", elements=2), 2 * math.pi))
    rng = np.random.default_rng(5)
    q = system.q_initial + 1e-3 * rng.standard_normal(system.n)
    lam = rng.standard_normal(system.m)
    return system, q, lam, 0.13


def _per_column(system, q, lam, t):
    """One Richardson difference per coordinate (every column, no pattern)."""
    h = po.fd_steps(q, po.RICHARDSON_STEP)
    out = np.zeros((system.n, system.n))
    for j in range(system.n):
        e = np.zeros(system.n)
        e[j] = 1.0
        out[:, j] = po._richardson(lambda x: system.constraint_jacobian(x, t).T @ lam, q, e, h[j])
    return out


def test_coloured_reaction_stiffness_equals_one_column_at_a_time():
    """Two-link arm (revolute elbow, two clamps): the compressed differences of d(C_q^T lambda)/dq
    equal one difference per column (same rule and steps; a row sees one column per colour, so
    only round-off of the shared evaluation differs: <= 1e-12 of the largest entry), with fewer
    evaluations."""
    system, q, lam, t = _two_link_state()
    pattern = system.coupling_pattern()
    Kr = po._reaction_stiffness(system, q, lam, t, po.RICHARDSON_STEP, True, pattern)
    ref = _per_column(system, q, lam, t)
    assert np.max(np.abs(ref)) > 0
    assert np.max(np.abs(Kr - ref)) <= 1e-12 * np.max(np.abs(ref))
    assert len(pattern.reaction_colours) < len(system.reaction_columns())


def test_wrong_reaction_pattern_is_caught_by_the_directional_check(monkeypatch):
    """A colouring that puts coupled columns together gives a wrong stiffness; the directional
    check must notice and fall back to one column at a time (switching the check off shows
    the wrong answer it prevents)."""
    from linearize import collocation_solver as cs

    system, q, lam, t = _two_link_state()
    good = system.coupling_pattern()
    cols = np.flatnonzero(np.any(good.reaction, axis=0))
    wrong = cs.CouplingPattern(force=good.force, reaction=good.reaction, force_colours=good.force_colours,
                               reaction_colours=(cols,))
    ref = _per_column(system, q, lam, t)
    fixed = po._reaction_stiffness(system, q, lam, t, po.RICHARDSON_STEP, True, wrong)
    assert np.max(np.abs(fixed - ref)) <= 1e-12 * np.max(np.abs(ref))
    monkeypatch.setattr(cs, "PATTERN_CHECK_TOLERANCE", math.inf)
    unchecked = po._reaction_stiffness(system, q, lam, t, po.RICHARDSON_STEP, True, wrong)
    assert np.max(np.abs(unchecked - ref)) > 1e-3 * np.max(np.abs(ref))


# --------------------------------------------------------------------------- continuation in omega
#: The soft link of tests/test_config.py: E = 2e7 N/m^2 (Table 1: 7.11e10).
SOFT_E = 2e7


def _soft_params():
    from mbs_models.parameters import ManipulatorParameters

    return ManipulatorParameters(youngs_modulus=SOFT_E)


def _record_omegas(monkeypatch) -> list:
    """Every omega a collocation is built at (the target and each continuation solve), in order."""
    omegas: list = []
    real = po._Collocation.__init__

    def recording(self, built, samples, solver="auto"):
        omegas.append(float(built.omega))
        real(self, built, samples, solver)

    monkeypatch.setattr(po._Collocation, "__init__", recording)
    return omegas


def test_continuation_without_a_start_gives_up_at_an_eighth_of_omega(monkeypatch):
    """Soft link, 1 element, 2 pi: Newton fails from every guess at omega and continuation finds no orbit
    to start from at omega/2, /4, /8; it stops there (halving on, down to its solve budget omega/2^40,
    costs ~15 min of ever longer guess periods, no better a guess).  One line, "did not converge" and the
    starts tried; never "no periodic orbit" (one exists, tests/test_config.py)."""
    omega = 2 * math.pi
    omegas = _record_omegas(monkeypatch)
    with pytest.raises(OrbitConvergenceError) as err:
        find_orbit("single-link", omega, elements=1, params=_soft_params(), verify=False)
    lowest = po.CONTINUATION_START * 0.5 ** po.CONTINUATION_START_HALVINGS
    assert lowest == 0.125
    assert [w / omega for w in omegas] == pytest.approx([1.0, 0.5, 0.25, 0.125], rel=1e-12)
    msg = str(err.value)
    assert len(msg.splitlines()) == 1 and "did not converge" in msg
    assert "found no orbit to start from at 0.5 down to 0.125 omega" in msg and "no periodic orbit" not in msg
    assert min(err.value.residuals) > po.DEFAULT_TOLERANCE


def test_continuation_in_omega_still_finds_the_orbit_at_11_pi(monkeypatch):
    """1 element, 32 samples, 11 pi: Newton fails from both guesses at omega (``continuation=False``
    raises); continuation from omega/2 converges at omega, through a step that fails and is halved (the
    early give-up of a continuation solve), and Exudyn's integrator confirms the orbit."""
    omega = 11 * math.pi
    with pytest.raises(OrbitConvergenceError, match="did not converge"):
        find_orbit("single-link", omega, samples=32, elements=1, continuation=False, verify=False)
    omegas = _record_omegas(monkeypatch)
    orbit = find_orbit("single-link", omega, samples=32, elements=1, verify=True)
    assert orbit.tolerance == po.DEFAULT_TOLERANCE and orbit.residual <= orbit.tolerance
    assert orbit.shooting_residual <= po.SHOOTING_TOLERANCE
    factors = [w / omega for w in omegas]
    assert factors[0] == 1.0 and factors[1] == pytest.approx(po.CONTINUATION_START) and factors[-1] == 1.0
    assert any(b < a for a, b in zip(factors[1:], factors[2:]))  # a failed step was retried shorter


@pytest.mark.slow
def test_the_orbit_continuation_finds_at_11_pi_is_the_hand_routes():
    """4 elements, 32 samples, 11 pi (needs continuation): the orbit is the hand-derived route's (other
    coordinates, other code), not another periodic solution.  Torques within 1e-6 of the largest, each
    route's relative residual tolerance (measured 1.1e-9); another orbit differs at O(1)."""
    from _link_oracle.exudyn_link import ExudynLinkConfig
    from _link_oracle.link_orbit import find_periodic_orbit

    omega = 11 * math.pi
    with pytest.raises(OrbitConvergenceError):
        find_orbit("single-link", omega, samples=32, elements=4, continuation=False, verify=False)
    orbit = find_orbit("single-link", omega, samples=32, elements=4, verify=True)
    assert orbit.residual <= orbit.tolerance and orbit.shooting_residual <= po.SHOOTING_TOLERANCE
    hand = find_periodic_orbit(None, ExudynLinkConfig(elements=4, drive="free", omega=omega), samples=32,
                               verify=False)
    np.testing.assert_allclose(orbit.torques[:, 0], hand.hub_torques, rtol=0,
                               atol=1e-6 * np.max(np.abs(hand.hub_torques)))


def test_a_transient_swing_of_a_soft_link_is_not_reported_as_growth(monkeypatch):
    """Soft link, 8 elements, 2 pi: over the simulated guess period an ANCF slope coordinate swings
    monotonically by -1.97 (most of its range), over the next by -0.015: a transient, not growth, so no
    "no periodic orbit" verdict.  On the first period alone (``GROWTH_REPEAT = 0``) it would be one."""
    from mbs_models.model_file import build_model, resolve_model

    definition = resolve_model("single-link", elements=8, params=_soft_params())
    col = po._Collocation(build_model(definition, 2 * math.pi), 32)
    po._guess(col, definition)
    assert po._growing_coordinates(col) == ""
    monkeypatch.setattr(po, "GROWTH_REPEAT", 0.0)
    assert re.search(r"link\[18\] advances by -1\.9", po._growing_coordinates(col))
