"""Rigid symmetric rotor on two isotropic bearings, spinning about its axis x at constant speed.

The rotor's node is a ``NodeRigidBodyRxyz`` (Tait-Bryan angles x-y-z); the spin angle (the first
angle, coordinate 3) is a drive with ``motion = (Omega t, Omega, 0)``: one whole turn per period.
Bearings: ``CartesianSpringDamper``s between the rotor's axis points ``x = +-A`` and the ground, each
with stiffness ``(KX, K, K)`` and damping ``(C, C, C)``.  In a frame fixed in space the linearisation
has constant coefficients (translations ``m u'' + 2 C u' + 2 K u = 0``, tilts with the gyroscopic
coupling ``J_t beta'' + J_p Omega gamma' + 2 C A^2 beta' + 2 K A^2 beta = 0`` and the mirror equation),
so the multipliers are ``exp(lambda T)`` (tests/test_rotating_orbits.py).
"""
from exudyn.itemInterface import (CartesianSpringDamper, MarkerBodyPosition, MarkerNodeCoordinate, NodePointGround,
                                  NodeRigidBodyRxyz, ObjectGround, ObjectRigidBody)

MASS = 2.0
J_POLAR, J_TRANSVERSE = 0.01, 0.05   # inertia about the axis and about a transverse axis (kg m^2)
A = 0.2                              # centre -> bearing (m)
K, KX, C = 4.0e3, 2.0e3, 2.0         # bearing stiffness (radial, axial) and damping


def build(mbs, omega):
    ground = mbs.AddObject(ObjectGround())
    gnode = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gnode, coordinate=0))
    n = mbs.AddNode(NodeRigidBodyRxyz(referenceCoordinates=[0, 0, 0, 0, 0, 0],
                                      initialVelocities=[0, 0, 0, omega, 0, 0]))
    rotor = mbs.AddObject(ObjectRigidBody(nodeNumber=n, mass=MASS,
                                          inertia=[J_POLAR, J_TRANSVERSE, J_TRANSVERSE, 0, 0, 0], name="rotor"))
    for side in (-1.0, 1.0):
        mr = mbs.AddMarker(MarkerBodyPosition(bodyNumber=rotor, localPosition=[side * A, 0, 0]))
        mgr = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[side * A, 0, 0]))
        mbs.AddObject(CartesianSpringDamper(markerNumbers=[mgr, mr], stiffness=[KX, K, K], damping=[C, C, C]))
    spin = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n, coordinate=3))
    return [{"name": "spin", "markers": (mg, spin), "motion": lambda t: (omega * t, omega, 0.0)}]
