"""3D spherical pendulum hanging from a vertically driven support; the pendulum's node is a
``NodeRigidBodyRxyz`` (Tait-Bryan angles).

The support point follows ``z_s(t) = a cos(omega t)`` through rheonomic ``CoordinateConstraint``s
(no drives); a spherical joint holds the pendulum's pivot on it; gravity is ``-g e_z``.  Hanging,
the two swing modes obey the damped-free Mathieu equation
``J_p th'' + m l (g - a omega^2 cos(omega t)) th = 0`` (``J_p = J_xx + m l^2``); the spin about
the vertical axis is free (a double multiplier 1, a Jordan block of the frozen-time system).
"""
import math

from exudyn.itemInterface import (CoordinateConstraint, LoadMassProportional, MarkerBodyMass,
                                  MarkerBodyPosition, MarkerNodeCoordinate, MarkerNodePosition, NodePoint,
                                  NodePointGround, NodeRigidBodyRxyz, ObjectJointSpherical, ObjectMassPoint,
                                  ObjectRigidBody)

MASS = 0.8
LENGTH = 0.3                          # pivot -> centre of mass
INERTIA = (0.01, 0.01, 0.002)         # principal inertia about the centre of mass (x, y, z)
AMPLITUDE = 0.01
GRAVITY = 9.81


def build(mbs, omega, amplitude=AMPLITUDE):
    ground = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    ns = mbs.AddNode(NodePoint(referenceCoordinates=[0, 0, 0], initialCoordinates=[0, 0, amplitude]))
    mbs.AddObject(ObjectMassPoint(nodeNumber=ns, mass=1.0, name="support"))
    ms = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ns, coordinate=c)) for c in range(3)]
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, ms[0]]))
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, ms[1]]))
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, ms[2]],
                                       offsetUserFunction=lambda mbs_, t, item, off: amplitude * math.cos(omega * t)))
    npd = mbs.AddNode(NodeRigidBodyRxyz(referenceCoordinates=[0, 0, -LENGTH, 0, 0, 0],
                                        initialCoordinates=[0, 0, amplitude, 0, 0, 0]))
    jx, jy, jz = INERTIA
    pend = mbs.AddObject(ObjectRigidBody(nodeNumber=npd, mass=MASS, inertia=[jx, jy, jz, 0, 0, 0], name="pendulum"))
    m_sup = mbs.AddMarker(MarkerNodePosition(nodeNumber=ns))
    m_pen = mbs.AddMarker(MarkerBodyPosition(bodyNumber=pend, localPosition=[0, 0, LENGTH]))
    mbs.AddObject(ObjectJointSpherical(markerNumbers=[m_sup, m_pen]))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=pend)),
                                     loadVector=[0, 0, -GRAVITY]))
    return []
