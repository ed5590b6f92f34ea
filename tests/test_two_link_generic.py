"""The two-link model file through the generic path (orbit, linearisation, labelled Floquet).

Oracle: a rigid two-link arm written here by hand (Lagrange's equations of
the same masses, inertias, gravity, joint damping and PD gains, linearised by
central differences about the prescribed motion, monodromy by DOP853 at rtol 1e-8,
far below the 1.5 % tolerance) -- nothing of the package is used.  The flexible arm's slow drive modes
differ from the rigid ones only by the quasi-static elastic correction, of
order (f_drive / f_bending)^2 <= (2 Hz / 16.4 Hz)^2 = 1.5 %: the tolerance.
"""
from __future__ import annotations

import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest
from scipy.integrate import solve_ivp

pytest.importorskip("exudyn")

from mbs_models.builtin.two_link import TwoLinkParameters  # noqa: E402

P = TwoLinkParameters()
ELASTIC_TOLERANCE = (2.0 / 16.4) ** 2  # quasi-static elastic correction of the drive modes
GAINS_2PI = (15.0, 8.94531, 7.14844, 1.45312)  # (kp1, kd1, kp2, kd2), tuned to rho_d = 0.3


def rigid_multipliers(omega, gains, gravity=P.gravity, tip_mass=P.tip_mass):
    l1, l2, mu = P.length1, P.length2, P.mass_per_length
    m1, m2 = mu * l1, mu * l2
    ma, sa = m2 + tip_mass, m2 * l2 / 2 + tip_mass * l2  # link 2 + tip about the elbow
    Ia = m2 * l2**2 / 3 + tip_mass * l2**2 + P.rotor_inertia
    I1 = P.hub_inertia + m1 * l1**2 / 3 + P.motor_mass * l1**2

    def residual(q, qd, qdd):
        c2, s2 = math.cos(q[1]), math.sin(q[1])
        M = np.array([[I1 + ma * l1**2 + Ia + 2 * l1 * sa * c2, Ia + l1 * sa * c2], [Ia + l1 * sa * c2, Ia]])
        h = np.array([-l1 * sa * s2 * (2 * qd[0] * qd[1] + qd[1] ** 2), l1 * sa * s2 * qd[0] ** 2])
        G = gravity * np.array([(m1 / 2 + P.motor_mass + ma) * l1 * math.cos(q[0]) + sa * math.cos(q[0] + q[1]),
                                sa * math.cos(q[0] + q[1])])
        return M @ qdd + h + G + P.joint_damping * np.asarray(qd), M

    A = math.pi / 4
    kp, kd = np.diag(gains[0::2]), np.diag(gains[1::2])
    e = 1e-6  # central differences of a smooth function: error ~ e^2

    def rhs(t, x):
        s, c = math.sin(omega * t), math.cos(omega * t)
        q = np.array([math.pi / 2 + A * s, A * s])
        qd = np.array([A * omega * c] * 2)
        qdd = np.array([-A * omega**2 * s] * 2)
        K, C = np.zeros((2, 2)), np.zeros((2, 2))
        for j in range(2):
            d = np.zeros(2)
            d[j] = e
            K[:, j] = (residual(q + d, qd, qdd)[0] - residual(q - d, qd, qdd)[0]) / (2 * e)
            C[:, j] = (residual(q, qd + d, qdd)[0] - residual(q, qd - d, qdd)[0]) / (2 * e)
        M = residual(q, qd, qdd)[1]
        X = x.reshape(4, 4)
        return np.vstack([X[2:], np.linalg.solve(M, -((C + kd) @ X[2:] + (K + kp) @ X[:2]))]).ravel()

    sol = solve_ivp(rhs, (0, 2 * math.pi / omega), np.eye(4).ravel(), rtol=1e-8, atol=1e-10, method="DOP853")
    mu_ = np.linalg.eigvals(sol.y[:, -1].reshape(4, 4))
    return mu_[np.argsort(-np.abs(mu_))]


@pytest.fixture(scope="module")
def orbit_2pi():
    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from mbs_models.model_file import builtin_model

    o = find_orbit(builtin_model("two-link", elements=2), 2 * math.pi)
    return o, linearize_orbit(o, 0.0, 0.0)


@pytest.mark.parametrize("gains", [(0.0, 0.0, 0.0, 0.0), GAINS_2PI])
def test_drive_mode_multiplier_against_rigid_two_link(orbit_2pi, gains):
    from flexstab.two_link import LabelledPlant
    from taguchi.tuning import GainObjective

    o, lin = orbit_2pi
    assert o.residual <= o.tolerance
    flexible = GainObjective(LabelledPlant(lin, o, {"method": "magnus2", "n_steps": 1024, "error_estimate": False}))(gains)
    rigid = abs(rigid_multipliers(2 * math.pi, gains)[0])
    assert abs(flexible - rigid) <= ELASTIC_TOLERANCE * rigid, (flexible, rigid)
    # rejects a wrong model: the rigid arm without gravity is far outside the bound
    no_gravity = abs(rigid_multipliers(2 * math.pi, gains, gravity=0.0)[0])
    assert abs(flexible - no_gravity) > ELASTIC_TOLERANCE * rigid


@pytest.mark.slow
@pytest.mark.parametrize("noise", [{"tip_mass": 0.2, "omega_scale": 1.1, "youngs_modulus_scale": 0.95},
                                   {"tip_mass": 0.05, "omega_scale": 0.9, "youngs_modulus_scale": 1.05}])
def test_noise_plant_of_the_robust_design_against_rigid_two_link(noise):
    """The robust design's plant at a noise value (payload, Omega, E) is the arm with those values: its
    Hill-measured drive-mode multiplier (1 element per link) against the rigid arm with that payload and
    Omega (elastic tolerance as above; E enters only through the elastic correction).  Rejects the
    nominal payload/Omega: outside the bound."""
    from flexstab.two_link import TwoLinkNoisePlant
    from stability.gains import Gains

    omega = 2 * math.pi
    plant = TwoLinkNoisePlant(omega, elements=1)(noise)
    g = GAINS_2PI
    flexible = plant.spectral_measure(*Gains.from_interleaved(g).arguments())
    w = omega * noise["omega_scale"]
    rigid = abs(rigid_multipliers(w, g, tip_mass=noise["tip_mass"])[0])
    assert abs(flexible - rigid) <= ELASTIC_TOLERANCE * rigid, (flexible, rigid)
    nominal = abs(rigid_multipliers(omega, g)[0])
    assert abs(flexible - nominal) > ELASTIC_TOLERANCE * rigid
