"""A rigid rod hanging from a support that oscillates along x (``direction="x"``, the rod swings about y)
or along z (``direction="z"``, the rod stays hanging), with a ``NodeRigidBodyEP`` (``node="EP"``), a
``NodeRigidBodyRxyz`` (``node="Rxyz"``) or a ``NodeRigidBodyRotVecLG`` (``node="RV"``) node.

The joint holds the pivot on the support and stops the rod turning about its own axis; gravity -g e_z;
a dashpot c on the centre of mass against the ground.
"""
import math

from exudyn.itemInterface import (CartesianSpringDamper, LoadMassProportional, MarkerBodyMass, MarkerBodyPosition,
                                  MarkerBodyRigid, NodeRigidBodyEP, NodeRigidBodyRotVecLG, NodeRigidBodyRxyz,
                                  ObjectGround, ObjectJointGeneric, ObjectRigidBody)

MASS, L, J_T, J_A = 1.0, 0.5, 0.02, 0.001
GRAVITY, DAMPING = 9.81, 0.05


def build(mbs, omega, node="EP", direction="x", amplitude=0.1):
    ground = mbs.AddObject(ObjectGround())
    if node == "EP":
        nr = mbs.AddNode(NodeRigidBodyEP(referenceCoordinates=[0, 0, -L, 1, 0, 0, 0]))
    elif node == "Rxyz":
        nr = mbs.AddNode(NodeRigidBodyRxyz(referenceCoordinates=[0, 0, -L, 0, 0, 0]))
    else:
        nr = mbs.AddNode(NodeRigidBodyRotVecLG(referenceCoordinates=[0, 0, -L, 0, 0, 0]))
    rod = mbs.AddObject(ObjectRigidBody(nodeNumber=nr, mass=MASS, inertia=[J_T, J_T, J_A, 0, 0, 0], name="rod"))
    support = mbs.AddMarker(MarkerBodyRigid(bodyNumber=ground, localPosition=[0, 0, 0]))
    pivot = mbs.AddMarker(MarkerBodyRigid(bodyNumber=rod, localPosition=[0, 0, L]))
    axis = 0 if direction == "x" else 2

    def offset(mbs_, t, item, off):
        out = [0.0] * 6
        out[axis] = amplitude * math.sin(omega * t)
        return out

    mbs.AddObject(ObjectJointGeneric(markerNumbers=[support, pivot], constrainedAxes=[1, 1, 1, 0, 0, 1],
                                     offsetUserFunction=offset))
    mbs.AddObject(CartesianSpringDamper(markerNumbers=[
        mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, -L])),
        mbs.AddMarker(MarkerBodyPosition(bodyNumber=rod, localPosition=[0, 0, 0]))],
        stiffness=[0, 0, 0], damping=[DAMPING] * 3))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=rod)),
                                     loadVector=[0, 0, -GRAVITY]))
    return []
