"""Exudyn link model, its periodic orbit, and bad input.

Oracles: finite differences of the coordinate map; second-order convergence of
Exudyn's own integrator onto the collocation orbit (cross-method); the
closed-loop model (feed-forward + PD inside Exudyn) keeps the orbit.
"""
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest

from _link_oracle.exudyn_link import ExudynLinkConfig, ExudynSolverError, build_link_model
from _link_oracle.link_orbit import OrbitConvergenceError, find_periodic_orbit, rigid_reference
from mbs_models.parameters import ManipulatorParameters


@pytest.fixture(scope="module")
def orbit2():
    # 2 elements keep the Exudyn runs short; the orbit method does not depend on it
    return find_periodic_orbit(config=ExudynLinkConfig(elements=2), samples=16, verify=False)


def test_coordinate_map_derivatives():
    m = build_link_model(config=ExudynLinkConfig(elements=3))
    rng = np.random.default_rng(1)
    p, v = m.rigid_configuration(0.7, 1.3)
    p = p + 1e-3 * rng.standard_normal(m.n)
    v = v + 1e-2 * rng.standard_normal(m.n)
    q, J = m.coordinates(p), m.jacobian(p)
    p2, v2 = m.independent(q, J @ v)
    # round trip g^-1(g(p)): a rotation and a shift each way, a few roundings of O(1) numbers per
    # entry: <= 16 eps max(1, |p|) (measured 1e-16); the rates also carry w |p| (the S u term).
    # (np.allclose's default rtol=1e-5 used to hide in the old check.)
    eps = np.finfo(float).eps
    np.testing.assert_allclose(p2, p, rtol=0, atol=16 * eps * max(1.0, np.max(np.abs(p))))
    np.testing.assert_allclose(v2, v, rtol=0,
                               atol=16 * eps * max(1.0, np.max(np.abs(v))) * max(1.0, np.max(np.abs(p))))
    h = 1e-6
    Jfd = np.array([(m.coordinates(p + h * e) - m.coordinates(p - h * e)) / (2 * h) for e in np.eye(m.n)]).T
    # central differences: h^2 |g'''| / 6 + eps |g| / h ~ 1e-12 + 2e-10 (|g| ~ 1 m, rad): 1e-8 is 50x
    assert np.max(np.abs(Jfd - J)) < 1e-8
    # q(t) = g(p + v t): q''(0) = J' v (the convective term), by central differences:
    # hs^2 |g''''| |v|^4 / 12 + 4 eps |g| / hs^2 ~ 1e-9 + 1e-7, against 1e-5 |q''| (|q''| ~ 1.3)
    hs = 1e-4
    qdd = (m.coordinates(p + hs * v) - 2 * q + m.coordinates(p - hs * v)) / hs**2
    assert np.max(np.abs(qdd - m.convective(p, v))) < 1e-5 * np.max(np.abs(qdd))


def test_mass_matrix_is_constant_and_symmetric():
    m = build_link_model(config=ExudynLinkConfig(elements=2))
    M = m.mass_matrix()
    assert np.allclose(M, M.T)
    # total translational mass of beam + tip from the x-rows of nodal positions
    ones = np.zeros(m.n_ode2)
    for i in m.node_index:
        ones[i] = 1.0
    p = ManipulatorParameters()
    assert ones @ M @ ones == pytest.approx(p.link_mass + p.tip_mass, rel=1e-12)


def test_orbit_converges_and_is_periodic(orbit2):
    assert orbit2.kind == "periodic"
    assert orbit2.residual < 1e-6
    # undeformed rigid motion is far from a solution (prestress)
    assert rigid_reference(config=ExudynLinkConfig(elements=2), samples=16).residual > 1.0
    # spectral accuracy in the samples: 16 and 32 collocation points agree
    o32 = find_periodic_orbit(config=ExudynLinkConfig(elements=2), samples=32, verify=False)
    scale = np.max(np.abs(orbit2.tip_deflection()))
    assert np.max(np.abs(o32.positions[::2] - orbit2.positions)) < 1e-6 * scale


def test_exudyn_integration_converges_to_orbit(orbit2):
    """Shooting with Exudyn from the orbit state: defect falls as h^2 (generalised-alpha)."""
    from _link_oracle.link_orbit import _shooting_defect

    cfg = orbit2.config
    model = build_link_model(orbit2.params, cfg)
    d = []
    for h in (2e-3, 1e-3):
        c = ExudynLinkConfig(elements=cfg.elements, omega=cfg.omega, step_size=h)
        d.append(_shooting_defect(orbit2.params, c, orbit2.positions[0], orbit2.velocities[0], model))
    assert d[1] < 0.01
    assert 3.0 < d[0] / d[1] < 5.0, d


def test_closed_loop_keeps_the_orbit(orbit2):
    """Free hub with feed-forward = orbit torque and PD inside Exudyn stays on the orbit."""
    cfg = ExudynLinkConfig(elements=2, drive="free", kp=37.1617, kd=29.2410)
    model = build_link_model(orbit2.params, cfg, feedforward=orbit2.hub_torque)
    res = model.simulate(orbit2.positions[0], orbit2.velocities[0], orbit2.period, record=True)
    # hub angle error against q_a^R(t) stays at the integrator's error level
    qr = math.pi / 2 + math.pi / 2 * np.sin(cfg.omega * res.times)
    assert np.max(np.abs(res.hub_angle - qr)) < 1e-4
    # tip deflection follows the orbit's (sampled at the orbit times)
    k = np.searchsorted(res.times, orbit2.times[4])
    assert res.tip_deflection[k] == pytest.approx(orbit2.tip_deflection()[4], rel=0.02)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"elements": 0}, "elements"),
        ({"elements": 2.5}, "elements"),
        ({"drive": "magic"}, "drive"),
        ({"omega": 0.0}, "omega"),
        ({"kp": -1.0}, "kp"),
        ({"bending_damping": float("nan")}, "bending_damping"),
    ],
)
def test_bad_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ExudynLinkConfig(**kwargs)


def test_orbit_not_converging_reports_residuals():
    with pytest.raises(OrbitConvergenceError, match="did not converge") as exc:
        find_periodic_orbit(
            config=ExudynLinkConfig(elements=2), samples=8, max_iterations=1, verify=False, continuation=False
        )
    assert isinstance(exc.value, RuntimeError)
    assert len(exc.value.residuals) == 1 and exc.value.residuals[0] > 1e-6


def test_solver_failure_is_reported():
    m = build_link_model(config=ExudynLinkConfig(elements=2, drive="free"), feedforward=lambda t: float("nan"))
    p, v = m.rigid_configuration(math.pi / 2, math.pi**2 / 2)
    with pytest.raises(ExudynSolverError, match="Exudyn time integration"):
        m.simulate(p, v, 0.01)
    with pytest.raises(ValueError, match="NaN"):
        m.simulate(p * np.nan, v, 0.01)
