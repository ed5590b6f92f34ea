"""A rigid rod hanging from a support that oscillates vertically (a 3D pendulum with Euler parameters).

The rod (mass m, centre of mass a distance L below the pivot, inertia J_t about transverse axes through
its centre, J_a about its own axis) hangs from a joint that holds the pivot on the support and stops
the rod turning about the vertical; the support moves as z(t) = A sin(omega t) (the joint's offset).
Gravity -g e_z; a dashpot c on the centre of mass against the ground.
"""
import math

from exudyn.itemInterface import (CartesianSpringDamper, LoadMassProportional, MarkerBodyMass, MarkerBodyPosition,
                                  MarkerBodyRigid, NodeRigidBodyEP, ObjectGround, ObjectJointGeneric, ObjectRigidBody)

MASS, L, J_T, J_A = 1.0, 0.5, 0.02, 0.001
AMPLITUDE, GRAVITY, DAMPING = 0.05, 9.81, 0.05


def build(mbs, omega, amplitude=AMPLITUDE):
    ground = mbs.AddObject(ObjectGround())
    node = mbs.AddNode(NodeRigidBodyEP(referenceCoordinates=[0, 0, -L, 1, 0, 0, 0]))
    rod = mbs.AddObject(ObjectRigidBody(nodeNumber=node, mass=MASS, inertia=[J_T, J_T, J_A, 0, 0, 0], name="rod"))
    support = mbs.AddMarker(MarkerBodyRigid(bodyNumber=ground, localPosition=[0, 0, 0]))
    pivot = mbs.AddMarker(MarkerBodyRigid(bodyNumber=rod, localPosition=[0, 0, L]))
    mbs.AddObject(ObjectJointGeneric(
        markerNumbers=[support, pivot], constrainedAxes=[1, 1, 1, 0, 0, 1],
        offsetUserFunction=lambda mbs_, t, item, offset: [0, 0, amplitude * math.sin(omega * t), 0, 0, 0]))
    mbs.AddObject(CartesianSpringDamper(markerNumbers=[
        mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, -L])),
        mbs.AddMarker(MarkerBodyPosition(bodyNumber=rod, localPosition=[0, 0, 0]))],
        stiffness=[0, 0, 0], damping=[DAMPING] * 3))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=rod)),
                                     loadVector=[0, 0, -GRAVITY]))
    return []
