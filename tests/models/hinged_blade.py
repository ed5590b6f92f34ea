"""Hinged blade on a hub turning at constant speed in a vertical plane (gravity -y).

The hub (a rigid body held at the origin) turns at ``Omega``; a rigid blade is hinged
to it at radius ``R`` with a hinge spring ``k`` and damper ``c``.  The blade's angle
relative to the hub, ``beta``, obeys (the hand derivation in tests/test_rotating_orbits.py)::

    J_p beta'' + c beta' + m R s Omega^2 sin(beta) + m g s cos(Omega t + beta) + k beta = 0,

``J_p = J + m s^2``, ``s`` the hinge -> centre-of-mass distance.

``form="drive"``: the hub angle is a drive whose motion is ``(Omega t, Omega, 0)``; it
advances by 2 pi per period (a whole turn).  ``form="constraint"``: no drive, the hub
angle is held by a ``CoordinateConstraint`` whose offset user function returns
``Omega t``.  The hub inertia ``J_HUB`` matters only when the drive is released
under PD (``flexstab tune`` / ``validate``).  ``turns``: the hub makes this many turns per
period (hub speed ``turns * Omega``; a fractional value has no periodic orbit).
"""
import math

from exudyn.itemInterface import (CoordinateConstraint, CoordinateSpringDamper, LoadMassProportional,
                                  MarkerBodyMass, MarkerBodyPosition, MarkerNodeCoordinate, NodePointGround,
                                  NodeRigidBody2D, ObjectJointRevolute2D, ObjectRigidBody2D)

MASS, INERTIA = 0.5, 0.004      # blade mass (kg), inertia about its centre of mass (kg m^2)
RADIUS, ARM = 0.2, 0.15         # hub axis -> hinge, hinge -> blade centre of mass (m)
STIFFNESS, DAMPING = 2.0, 0.02  # hinge spring (N m/rad) and damper (N m s/rad)
J_HUB = 0.05                    # hub inertia about its axis (kg m^2)
GRAVITY = 9.81


def build(mbs, omega, form="drive", turns=1):
    ground = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    w = turns * omega  # hub speed: `turns` whole turns per period T = 2 pi / omega
    nh = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0, 0, 0], initialVelocities=[0, 0, w]))
    hub = mbs.AddObject(ObjectRigidBody2D(nodeNumber=nh, mass=1.0, inertia=J_HUB, name="hub"))
    mh = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nh, coordinate=c)) for c in range(3)]
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, mh[0]]))
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, mh[1]]))
    x = RADIUS + ARM
    nb = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[x, 0, 0], initialVelocities=[0, x * w, w]))
    blade = mbs.AddObject(ObjectRigidBody2D(nodeNumber=nb, mass=MASS, inertia=INERTIA, name="blade"))
    m_hub = mbs.AddMarker(MarkerBodyPosition(bodyNumber=hub, localPosition=[RADIUS, 0, 0]))
    m_bl = mbs.AddMarker(MarkerBodyPosition(bodyNumber=blade, localPosition=[-ARM, 0, 0]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[m_hub, m_bl]))
    mb = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nb, coordinate=2))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[mh[2], mb], stiffness=STIFFNESS, damping=DAMPING))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=blade)),
                                     loadVector=[0, -GRAVITY, 0]))
    if form == "constraint":
        mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, mh[2]],
                                           offsetUserFunction=lambda mbs_, t, item, off: w * t))
        return []
    if form != "drive":
        raise ValueError(f"form must be 'drive' or 'constraint', got {form!r}")
    return [{"name": "hub", "markers": (mg, mh[2]), "motion": lambda t: (w * t, w, 0.0)}]
