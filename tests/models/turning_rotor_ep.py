"""A rigid rotor on two bearings spinning freely about x, with a ``NodeRigidBodyEP`` node (``node="EP"``)
or a ``NodeRigidBodyRotVecLG`` node (``node="RV"``): after one period (a whole turn) the Euler
parameters come back with the opposite sign, the rotation vector passes its singular length 2 pi.
"""
from exudyn.itemInterface import (NodeRigidBodyRotVecLG, CartesianSpringDamper, MarkerBodyPosition, NodeRigidBodyEP, ObjectGround, ObjectRigidBody)
def build(mbs, omega, node="EP", held=False):
    """The rotor spins at omega: one whole turn per period."""
    ground = mbs.AddObject(ObjectGround())
    n = mbs.AddNode((NodeRigidBodyEP(referenceCoordinates=[0, 0, 0, 1, 0, 0, 0], initialVelocities=[0, 0, 0, 0, 0.5*omega, 0, 0]) if node == "EP" else NodeRigidBodyRotVecLG(referenceCoordinates=[0]*6, initialVelocities=[0,0,0,omega,0,0])))
    rotor = mbs.AddObject(ObjectRigidBody(nodeNumber=n, mass=2.0, inertia=[0.01, 0.05, 0.05, 0, 0, 0], name="rotor"))
    for side in (-1.0, 1.0):
        mr = mbs.AddMarker(MarkerBodyPosition(bodyNumber=rotor, localPosition=[side * 0.2, 0, 0]))
        mgr = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[side * 0.2, 0, 0]))
        mbs.AddObject(CartesianSpringDamper(markerNumbers=[mgr, mr], stiffness=[2e3, 4e3, 4e3], damping=[2, 2, 2]))
    if held:  # spin held at omega t by a generic joint on the rotation about x (tilts free): not autonomous
        from exudyn.itemInterface import MarkerBodyRigid, ObjectJointGeneric

        mr = mbs.AddMarker(MarkerBodyRigid(bodyNumber=rotor, localPosition=[0, 0, 0]))
        mgr = mbs.AddMarker(MarkerBodyRigid(bodyNumber=ground, localPosition=[0, 0, 0]))
        mbs.AddObject(ObjectJointGeneric(markerNumbers=[mgr, mr], constrainedAxes=[0, 0, 0, 1, 0, 0],
                                         offsetUserFunction=lambda mbs_, t, item, par: [0, 0, 0, omega * t, 0, 0]))
    return []
