"""A rigid rotor carried by a hub that turns at constant speed, through four elastic pads.

The hub (a ``NodeRigidBodyRxyz`` held at the origin) turns about x at omega: by a drive on its first
angle (``hub="drive"``, released under PD by the gains) or by a rheonomic ``CoordinateConstraint`` with
offset ``omega t`` (``hub="constraint"``, the default).  The rotor is a 3D rigid body with Euler parameters
(``node="EP"``, the default), Tait-Bryan angles (``node="Rxyz"``) or a rotation vector (``node="RV"``,
``NodeRigidBodyRotVecLG``), joined to the hub by four
isotropic ``CartesianSpringDamper`` pads at off-axis points, so that it turns with the hub: after one
period its Euler parameters come back with the opposite sign.  ``turns``: whole turns of the hub per
period ``2 pi / omega`` (its speed is ``turns * omega``).  Gravity along -y.
"""
from exudyn.itemInterface import (CartesianSpringDamper, CoordinateConstraint, LoadMassProportional, MarkerBodyMass,
                                  MarkerBodyPosition, MarkerNodeCoordinate, NodePointGround, NodeRigidBodyEP,
                                  NodeRigidBodyRotVecLG, NodeRigidBodyRxyz, ObjectRigidBody)

MASS, J_POLAR, J_TRANSVERSE = 2.0, 0.01, 0.05
PADS = [(0.2, 0.05, 0.0), (0.2, -0.05, 0.0), (-0.2, 0.0, 0.05), (-0.2, 0.0, -0.05)]
K, C = 4.0e3, 2.0


def build(mbs, omega, node="EP", hub="constraint", gravity=9.81, turns=1):
    omega = turns * omega  # the hub speed; the period stays 2 pi / omega of the call
    ground = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    nh = mbs.AddNode(NodeRigidBodyRxyz(referenceCoordinates=[0] * 6, initialVelocities=[0, 0, 0, omega, 0, 0]))
    hub_body = mbs.AddObject(ObjectRigidBody(nodeNumber=nh, mass=1.0, inertia=[0.02, 0.02, 0.02, 0, 0, 0],
                                             name="hub"))
    mh = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nh, coordinate=i)) for i in range(6)]
    for i in (0, 1, 2, 4, 5):  # the hub only turns about x
        mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, mh[i]]))
    if hub == "constraint":
        mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, mh[3]],
                                           offsetUserFunction=lambda mbs_, t, item, offset: omega * t))

    if node == "EP":  # Euler parameters (1, 0, 0, 0); spin omega about x: p' = (0, omega / 2, 0, 0)
        nr = mbs.AddNode(NodeRigidBodyEP(referenceCoordinates=[0, 0, 0, 1, 0, 0, 0],
                                         initialVelocities=[0, 0, 0, 0, 0.5 * omega, 0, 0]))
    elif node == "RV":  # body-fixed angular velocity (omega, 0, 0)
        nr = mbs.AddNode(NodeRigidBodyRotVecLG(referenceCoordinates=[0] * 6, initialVelocities=[0, 0, 0, omega, 0, 0]))
    else:
        nr = mbs.AddNode(NodeRigidBodyRxyz(referenceCoordinates=[0] * 6, initialVelocities=[0, 0, 0, omega, 0, 0]))
    rotor = mbs.AddObject(ObjectRigidBody(nodeNumber=nr, mass=MASS, inertia=[J_POLAR, J_TRANSVERSE, J_TRANSVERSE,
                                                                            0, 0, 0], name="rotor"))
    for p in PADS:
        mbs.AddObject(CartesianSpringDamper(markerNumbers=[
            mbs.AddMarker(MarkerBodyPosition(bodyNumber=hub_body, localPosition=list(p))),
            mbs.AddMarker(MarkerBodyPosition(bodyNumber=rotor, localPosition=list(p)))],
            stiffness=[K] * 3, damping=[C] * 3))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=rotor)),
                                     loadVector=[0, -gravity, 0]))
    if hub == "constraint":
        return []
    return [{"name": "hub", "markers": (mg, mh[3]), "motion": lambda t: (omega * t, omega, 0.0)}]
