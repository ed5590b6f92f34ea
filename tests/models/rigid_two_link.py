"""Rigid two-link arm (vertical plane) with two drives: shoulder (absolute angle) and elbow (relative).

The two-link arm's data (link lengths, section, density, hub and rotor
inertia, motor and tip mass, joint damping) with rigid links: body 1 is link 1
with the hub inertia, body 2 is link 2 with the motor mass at the elbow, the
rotor inertia and the tip mass.  Both joints move harmonically,
``phi1 = pi/2 + (pi/4) sin(W t)`` (absolute) and ``phi2 - phi1 = (pi/4) sin(W t)``;
with no control the linearisation about this motion has 4 states.  Reference
configuration = the state at t = 0; each drive's motion is the displacement of
its coordinate from there (Exudyn's ODE2 coordinates).
"""
import math

import numpy as np
from exudyn.itemInterface import (CoordinateSpringDamper, LoadMassProportional, MarkerBodyMass, MarkerBodyPosition,
                                  MarkerNodeCoordinate, NodePointGround, NodeRigidBody2D, ObjectGround,
                                  ObjectJointRevolute2D, ObjectRigidBody2D)

L1, L2 = 0.5, 0.4                        # link lengths (m)
RHO_A = 2700.0 * 4e-4                    # mass per length (kg/m)
J_HUB, J_ROTOR = 5.86e-5, 2e-5           # hub and elbow rotor inertia (kg m^2)
M_MOTOR, M_TIP = 0.2, 0.1                # motor mass at the elbow, tip mass (kg)
G = 9.81
ALPHA = 0.01                             # joint damping (N m s / rad)
MEAN1, AMP1 = 0.5 * math.pi, 0.25 * math.pi
AMP2 = 0.25 * math.pi

# body 1: link 1 (uniform rod) + hub inertia; centre of mass C1 from the shoulder
M1 = RHO_A * L1
C1 = 0.5 * L1
J1 = M1 * L1**2 / 12.0 + J_HUB
# body 2: link 2 + motor (at the elbow) + tip mass (at the tip) + rotor inertia
_m_rod = RHO_A * L2
M2 = _m_rod + M_MOTOR + M_TIP
C2 = (_m_rod * 0.5 * L2 + M_TIP * L2) / M2
J2 = (_m_rod * (L2**2 / 12.0 + (0.5 * L2 - C2) ** 2) + M_MOTOR * C2**2 + M_TIP * (L2 - C2) ** 2 + J_ROTOR)


def motions(omega):
    """Absolute shoulder angle and relative elbow angle with two derivatives, as functions of t."""
    def r1(t):
        s, c = math.sin(omega * t), math.cos(omega * t)
        return MEAN1 + AMP1 * s, AMP1 * omega * c, -AMP1 * omega**2 * s

    def r2(t):
        s, c = math.sin(omega * t), math.cos(omega * t)
        return AMP2 * s, AMP2 * omega * c, -AMP2 * omega**2 * s

    return r1, r2


def _e(phi):
    return np.array([math.cos(phi), math.sin(phi)])


def _en(phi):
    return np.array([-math.sin(phi), math.cos(phi)])


def build(mbs, omega):
    r1, r2 = motions(omega)
    p1, w1, _ = r1(0.0)
    rel, wrel, _ = r2(0.0)
    p2, w2 = p1 + rel, w1 + wrel
    x1 = C1 * _e(p1)
    v1 = C1 * w1 * _en(p1)
    x2 = L1 * _e(p1) + C2 * _e(p2)
    v2 = L1 * w1 * _en(p1) + C2 * w2 * _en(p2)
    ground = mbs.AddObject(ObjectGround())
    gnode = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gnode, coordinate=0))
    n1 = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[x1[0], x1[1], p1], initialVelocities=[v1[0], v1[1], w1]))
    n2 = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[x2[0], x2[1], p2], initialVelocities=[v2[0], v2[1], w2]))
    b1 = mbs.AddObject(ObjectRigidBody2D(nodeNumber=n1, mass=M1, inertia=J1, name="link 1"))
    b2 = mbs.AddObject(ObjectRigidBody2D(nodeNumber=n2, mass=M2, inertia=J2, name="link 2"))
    m_g = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, 0]))
    m_1a = mbs.AddMarker(MarkerBodyPosition(bodyNumber=b1, localPosition=[-C1, 0, 0]))
    m_1b = mbs.AddMarker(MarkerBodyPosition(bodyNumber=b1, localPosition=[L1 - C1, 0, 0]))
    m_2a = mbs.AddMarker(MarkerBodyPosition(bodyNumber=b2, localPosition=[-C2, 0, 0]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[m_g, m_1a]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[m_1b, m_2a]))
    for b in (b1, b2):
        mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=b)),
                                         loadVector=[0, -G, 0]))
    a1 = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n1, coordinate=2))
    a2 = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n2, coordinate=2))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[mg, a1], damping=ALPHA))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[a1, a2], damping=ALPHA))

    def d1(t):
        q, qt, qtt = r1(t)
        return q - p1, qt, qtt

    def d2(t):
        q, qt, qtt = r2(t)
        return q - rel, qt, qtt

    return [{"name": "shoulder", "markers": (mg, a1), "motion": d1},
            {"name": "elbow", "markers": (a1, a2), "motion": d2}]
