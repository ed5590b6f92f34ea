"""Rigid pendulum on a revolute joint whose support is driven vertically (no drives).

The support body follows ``y_s(t) = a cos(omega t)`` through a rheonomic
``CoordinateConstraint``; a rotational damper ``c`` acts on the joint angle.
About the hanging (``inverted=False``) or upright position the linearisation is
the damped Mathieu equation (see tests/test_constrained_linearisation.py)::

    J_p th'' + c th' +/- m l (g - a omega^2 cos(omega t)) th = 0,   J_p = J + m l^2.
"""
import math

import exudyn as exu
from exudyn.itemInterface import (CoordinateConstraint, CoordinateSpringDamper, MarkerBodyPosition,
                                  MarkerNodeCoordinate, NodePointGround, NodeRigidBody2D,
                                  ObjectJointRevolute2D, ObjectRigidBody2D, LoadForceVector, MarkerBodyMass,
                                  LoadMassProportional)

MASS = 0.8
INERTIA = 0.01      # about the centre of mass
LENGTH = 0.3        # pivot -> centre of mass
GRAVITY = 9.81
AMPLITUDE = 0.01    # support amplitude a
DAMPING = 0.02      # rotational damper c


def build(mbs, omega, amplitude=AMPLITUDE, damping=DAMPING, inverted=False):
    ground = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    # support: a rigid body whose x and angle are fixed and whose y follows a cos(omega t)
    ns = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0, 0, 0], initialCoordinates=[0, amplitude, 0]))
    support = mbs.AddObject(ObjectRigidBody2D(nodeNumber=ns, mass=1.0, inertia=1.0, name="support"))
    ms = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ns, coordinate=c)) for c in range(3)]
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, ms[0]]))
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, ms[2]]))
    mbs.AddObject(CoordinateConstraint(
        markerNumbers=[mg, ms[1]],
        offsetUserFunction=lambda mbs_, t, item, off: amplitude * math.cos(omega * t)))
    # pendulum body: centre of mass at distance LENGTH below (or above) the pivot
    sgn = 1.0 if inverted else -1.0
    phi0 = math.pi if inverted else 0.0
    npd = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0, sgn * LENGTH, phi0],
                                      initialCoordinates=[0, amplitude, 0]))
    pend = mbs.AddObject(ObjectRigidBody2D(nodeNumber=npd, mass=MASS, inertia=INERTIA, name="pendulum"))
    # pivot in the pendulum's body frame: LENGTH above the centre of mass (for phi = 0)
    m_sup = mbs.AddMarker(MarkerBodyPosition(bodyNumber=support, localPosition=[0, 0, 0]))
    m_pen = mbs.AddMarker(MarkerBodyPosition(bodyNumber=pend, localPosition=[0, LENGTH, 0]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[m_sup, m_pen]))
    mp = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=npd, coordinate=2))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[ms[2], mp], stiffness=0.0, damping=damping))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=pend)),
                                     loadVector=[0, -GRAVITY, 0]))
    return []
