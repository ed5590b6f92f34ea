"""A rigid rotor on two elastic bearings, spun by a motor whose torque follows its speed characteristic
``tau = c (Omega - theta')`` (no time in the model: autonomous), with a ``NodeRigidBodyRxyz`` node.

The motor settles the spin at ``theta' = Omega``: one whole turn per period ``T = 2 pi / Omega``.  The
orbit's phase is free (any time shift of the spin is an orbit), so one multiplier 1 is structural; the
spin rate itself is damped: the rotor is symmetric about x and its bearings are symmetric in y and z,
so a perturbation of the spin rate obeys ``J_x d' = -c d``, whose multiplier is ``exp(-c T / J_x)``.
"""
from exudyn.itemInterface import (CartesianSpringDamper, CoordinateSpringDamper, MarkerBodyPosition,
                                  MarkerNodeCoordinate, NodeRigidBodyRxyz, ObjectGround, ObjectRigidBody)

#: rotor inertia about its axis and the motor's torque-speed slope
INERTIA_X = 0.01
MOTOR_SLOPE = 0.004


def build(mbs, omega, motor=MOTOR_SLOPE):
    """Rotor spinning about x at omega, held by two bearings, its speed set by the motor characteristic."""
    ground = mbs.AddObject(ObjectGround())
    n = mbs.AddNode(NodeRigidBodyRxyz(referenceCoordinates=[0] * 6, initialVelocities=[0, 0, 0, omega, 0, 0]))
    rotor = mbs.AddObject(ObjectRigidBody(nodeNumber=n, mass=2.0, inertia=[INERTIA_X, 0.05, 0.05, 0, 0, 0],
                                          name="rotor"))
    for side in (-1.0, 1.0):
        mr = mbs.AddMarker(MarkerBodyPosition(bodyNumber=rotor, localPosition=[side * 0.2, 0, 0]))
        mg = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[side * 0.2, 0, 0]))
        mbs.AddObject(CartesianSpringDamper(markerNumbers=[mg, mr], stiffness=[2e3, 4e3, 4e3], damping=[2, 2, 2]))
    gn = mbs.AddNode(__import__("exudyn").itemInterface.NodePointGround(referenceCoordinates=[0, 0, 0]))
    mgc = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gn, coordinate=0))
    mrc = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n, coordinate=3))

    def motor_torque(mbs_, t, item, u, v, k, d, offset):  # force on the rotor coordinate: -(returned)
        return -motor * (omega - v)

    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[mgc, mrc], stiffness=0.0, damping=0.0,
                                         springForceUserFunction=motor_torque))
    return []
