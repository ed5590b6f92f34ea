"""Direct Exudyn monodromy of a model file (validation.direct_monodromy).

Oracle: a rigid pendulum on a revolute joint (a constrained model: its node
sits at the centre of mass, the joint holds the pivot at O), driven at its
angle by feed-forward + PD.  The feed-forward is written by hand,
``tau_ff = J_O qR'' + alpha qR' + m g l cos qR``, and the linearisation about
``qR(t)`` is the Hill equation

    J_O y'' + (alpha + kd) y' + (kp - m g l sin qR(t)) y = 0,

whose multipliers come from scipy's ``solve_ivp`` (rtol 1e-11) -- nothing of
the package's orbit, linearisation or Floquet code is used.
"""
from __future__ import annotations

import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest
from scipy.integrate import solve_ivp

exu = pytest.importorskip("exudyn")
from exudyn.itemInterface import (  # noqa: E402
    CoordinateSpringDamper,
    LoadMassProportional,
    MarkerBodyMass,
    MarkerBodyPosition,
    MarkerNodeCoordinate,
    NodePointGround,
    NodeRigidBody2D,
    ObjectGround,
    ObjectJointRevolute2D,
    ObjectRigidBody2D,
)

from validation.direct_monodromy import direct_monodromy  # noqa: E402

M, L, JC, ALPHA, G = 0.5, 0.3, 0.01, 0.01, 9.81
JO = JC + M * L * L
OMEGA, A = 2 * math.pi, 0.5
KP, KD = 2.0, 0.05


def motion(t):
    s, c = math.sin(OMEGA * t), math.cos(OMEGA * t)
    return A * s, A * OMEGA * c, -A * OMEGA**2 * s


def build(mbs, omega):
    ground = mbs.AddObject(ObjectGround())
    gnode = mbs.AddNode(NodePointGround())
    m_ground = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gnode, coordinate=0))
    q, w, _ = motion(0.0)
    pos = L * np.array([math.cos(q), math.sin(q)])
    vel = w * L * np.array([-math.sin(q), math.cos(q)])
    node = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[L, 0, 0], initialCoordinates=[pos[0] - L, pos[1], q],
                                       initialVelocities=[vel[0], vel[1], w]))
    body = mbs.AddObject(ObjectRigidBody2D(mass=M, inertia=JC, nodeNumber=node))
    mg = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, 0]))
    mp = mbs.AddMarker(MarkerBodyPosition(bodyNumber=body, localPosition=[-L, 0, 0]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[mg, mp]))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=body)),
                                     loadVector=[0, -G, 0]))
    m_angle = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=node, coordinate=2))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[m_ground, m_angle], damping=ALPHA))
    return [{"name": "pivot", "markers": (m_ground, m_angle), "motion": motion}]


def feedforward(t):
    q, w, a = motion(t)
    return np.array([JO * a + ALPHA * w + M * G * L * math.cos(q)])


def orbit_state():
    q, w, _ = motion(0.0)
    return (np.array([L * math.cos(q) - L, L * math.sin(q), q]),
            np.array([-w * L * math.sin(q), w * L * math.cos(q), w]))


def hill_multipliers(gravity_term=True):
    def rhs(t, x):
        q = motion(t)[0]
        k = KP - (M * G * L * math.sin(q) if gravity_term else 0.0)
        y = x.reshape(2, 2)
        return np.vstack([y[1], -(k * y[0] + (ALPHA + KD) * y[1]) / JO]).ravel()

    sol = solve_ivp(rhs, (0, 2 * math.pi / OMEGA), np.eye(2).ravel(), rtol=1e-11, atol=1e-13, method="DOP853")
    return np.sort_complex(np.linalg.eigvals(sol.y[:, -1].reshape(2, 2)))


def test_direct_monodromy_matches_hill_equation():
    q0, v0 = orbit_state()
    res = direct_monodromy(build, OMEGA, q0, v0, feedforward, kp=KP, kd=KD)
    assert res.basis.shape == (3, 1) and res.simulations == 3
    # the hand-written orbit closes in Exudyn (2nd-order integrator, h = 1e-3: ~1e-6)
    assert res.defect < 1e-4
    exact = hill_multipliers()
    got = np.sort_complex(res.multipliers)
    # budget: generalised alpha (w h)^2/12 ~ 2e-6 of the phase (w ~ 5 rad/s, h = 1e-3),
    # forward differences O(eps) = 1e-6, Newton tolerance 1e-10 / eps = 1e-4 at worst
    assert np.max(np.abs(got - exact)) < 1e-4, (got, exact)
    # rejects a wrong linearisation: without the gravity term of K(t)
    wrong = hill_multipliers(gravity_term=False)
    assert np.max(np.abs(got - wrong)) > 10 * 1e-4


def test_direct_monodromy_gain_count_must_match_drives():
    q0, v0 = orbit_state()
    with pytest.raises(ValueError, match="kp"):
        direct_monodromy(build, OMEGA, q0, v0, feedforward, kp=[1.0, 2.0])
