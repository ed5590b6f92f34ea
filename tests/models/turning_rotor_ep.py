"""A rigid rotor on two bearings spinning freely about x, with a ``NodeRigidBodyEP`` node (``node="EP"``)
or a ``NodeRigidBodyRotVecLG`` node (``node="RV"``): after one period (a whole turn) the Euler
parameters come back with the opposite sign, the rotation vector passes its singular length 2 pi.

``body_frame`` (rotation-vector node only): the body's own frame is turned by this rotation vector against
its principal axes (the node's reference rotation vector; inertia, marker positions and initial angular
velocity written in that frame), so the spin axis is no axis of the body's frame -- the same physical
rotor.
"""
import numpy as np
from exudyn.itemInterface import (NodeRigidBodyRotVecLG, CartesianSpringDamper, MarkerBodyPosition, NodeRigidBodyEP,
                                  ObjectGround, ObjectRigidBody)
from scipy.spatial.transform import Rotation

INERTIA = np.diag([0.01, 0.05, 0.05])


def build(mbs, omega, node="EP", held=False, body_frame=(0.0, 0.0, 0.0)):
    """The rotor spins at omega: one whole turn per period."""
    Rb = Rotation.from_rotvec(np.asarray(body_frame, dtype=float)).as_matrix()
    ground = mbs.AddObject(ObjectGround())
    if node == "EP":
        n = mbs.AddNode(NodeRigidBodyEP(referenceCoordinates=[0, 0, 0, 1, 0, 0, 0],
                                        initialVelocities=[0, 0, 0, 0, 0.5 * omega, 0, 0]))
        J = INERTIA
    else:
        n = mbs.AddNode(NodeRigidBodyRotVecLG(referenceCoordinates=[0, 0, 0, *[float(x) for x in body_frame]],
                                              initialVelocities=[0, 0, 0, *(Rb.T @ [omega, 0.0, 0.0])]))
        J = Rb.T @ INERTIA @ Rb
    rotor = mbs.AddObject(ObjectRigidBody(nodeNumber=n, mass=2.0, name="rotor",
                                          inertia=[J[0, 0], J[1, 1], J[2, 2], J[1, 2], J[0, 2], J[0, 1]]))
    local = (lambda p: list(Rb.T @ np.asarray(p, dtype=float))) if node != "EP" else list
    for side in (-1.0, 1.0):
        mr = mbs.AddMarker(MarkerBodyPosition(bodyNumber=rotor, localPosition=local([side * 0.2, 0, 0])))
        mgr = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[side * 0.2, 0, 0]))
        mbs.AddObject(CartesianSpringDamper(markerNumbers=[mgr, mr], stiffness=[2e3, 4e3, 4e3], damping=[2, 2, 2]))
    if held:  # spin held at omega t by a generic joint on the rotation about x (tilts free): not autonomous
        import exudyn as exu
        from exudyn.itemInterface import MarkerBodyRigid, ObjectJointGeneric

        if node == "EP":
            mr = mbs.AddMarker(MarkerBodyRigid(bodyNumber=rotor, localPosition=[0, 0, 0]))
        else:  # the joint's frame on the rotor: its principal axes
            mr = mbs.AddMarker(MarkerBodyRigid(bodyNumber=rotor, localHT=exu.HT(rotation=Rb.T, translation=[0, 0, 0])))
        mgr = mbs.AddMarker(MarkerBodyRigid(bodyNumber=ground, localPosition=[0, 0, 0]))
        mbs.AddObject(ObjectJointGeneric(markerNumbers=[mgr, mr], constrainedAxes=[0, 0, 0, 1, 0, 0],
                                         offsetUserFunction=lambda mbs_, t, item, par: [0, 0, 0, omega * t, 0, 0]))
    return []
