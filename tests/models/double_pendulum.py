"""Rigid double pendulum (vertical plane) with two joint drives: shoulder (absolute) and elbow (relative).

Reference configuration = the state at t = 0; each drive's motion is the
displacement of its coordinate from there (Exudyn's ODE2 coordinates).
"""
import math

import numpy as np
from exudyn.itemInterface import (CoordinateSpringDamper, LoadMassProportional, MarkerBodyMass, MarkerBodyPosition,
                                  MarkerNodeCoordinate, NodePointGround, NodeRigidBody2D, ObjectGround,
                                  ObjectJointRevolute2D, ObjectRigidBody2D)

M1, J1, C1, L1 = 1.0, 0.02, 0.25, 0.5   # mass, inertia about COM, joint->COM, joint->joint
M2, J2, C2 = 0.6, 0.01, 0.2
G = 9.81
ALPHA = 0.01                             # joint damping (N m s / rad)
MEAN1, AMP1 = -0.5 * math.pi, 0.6        # shoulder: phi1 = MEAN1 + AMP1 sin(W t)
AMP2, PHASE2 = 0.4, 0.5                  # elbow:    phi2 - phi1 = AMP2 sin(W t + PHASE2)


def motions(omega):
    """Absolute shoulder angle and relative elbow angle with two derivatives, as functions of t."""
    def r1(t):
        s, c = math.sin(omega * t), math.cos(omega * t)
        return MEAN1 + AMP1 * s, AMP1 * omega * c, -AMP1 * omega**2 * s

    def r2(t):
        s, c = math.sin(omega * t + PHASE2), math.cos(omega * t + PHASE2)
        return AMP2 * s, AMP2 * omega * c, -AMP2 * omega**2 * s

    return r1, r2


def _e(phi):
    return np.array([math.cos(phi), math.sin(phi)])


def _en(phi):
    return np.array([-math.sin(phi), math.cos(phi)])


def build(mbs, omega):
    return build_arm(mbs, motions(omega), M1=M1, J1=J1, C1=C1, L1=L1, M2=M2, J2=J2, C2=C2, alpha=ALPHA)


def build_arm(mbs, motions, *, M1, J1, C1, L1, M2, J2, C2, alpha):
    """Two rigid bodies on revolute joints, gravity, joint dampers, shoulder and elbow drives.

    ``motions = (r1, r2)``: absolute shoulder angle and relative elbow angle, each
    ``t -> (q, q_t, q_tt)``; body ``i`` has mass ``Mi``, inertia ``Ji`` about its centre of
    mass at ``Ci`` from its proximal joint, and ``L1`` is the shoulder-elbow distance.
    """
    r1, r2 = motions
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
    b1 = mbs.AddObject(ObjectRigidBody2D(nodeNumber=n1, mass=M1, inertia=J1, name="upper arm"))
    b2 = mbs.AddObject(ObjectRigidBody2D(nodeNumber=n2, mass=M2, inertia=J2, name="forearm"))
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
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[mg, a1], damping=alpha))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[a1, a2], damping=alpha))

    def d1(t):
        q, qt, qtt = r1(t)
        return q - p1, qt, qtt

    def d2(t):
        q, qt, qtt = r2(t)
        return q - rel, qt, qtt

    return [{"name": "shoulder", "markers": (mg, a1), "motion": d1},
            {"name": "elbow", "markers": (a1, a2), "motion": d2}]
