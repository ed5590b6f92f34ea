"""An unbalanced Jeffcott rotor: a disk on an anisotropic shaft whose bearing axis is the origin.

The disk's centre (a point mass in the plane normal to the shaft) is held by the rotating shaft's
anisotropic stiffness (``k_xi`` along the shaft-fixed axis ``(cos wt, sin wt)``, ``k_eta`` across it),
damped externally, pulled down by gravity and driven by its unbalance ``m e w^2`` turning with the
shaft.  At the default speed the synchronous whirl passes a few hundredths of a millimetre from the
bearing axis.  The linearisation does not depend on the orbit (the model is linear): its multipliers
are the closed form of tests/_laval_oracle.py.
"""
import math

from exudyn.itemInterface import (LoadForceVector, MarkerNodePosition, MarkerBodyPosition, NodePoint2D,
                                  ObjectConnectorCartesianSpringDamper, ObjectGround, ObjectMassPoint2D)

MASS, K_XI, K_ETA, DAMPING, GRAVITY = 2.0, 2.0e4, 2.6e4, 2.0, 9.81
ECCENTRICITY = 1.0e-2  # m


def build(mbs, omega, eccentricity=ECCENTRICITY):
    ground = mbs.AddObject(ObjectGround())
    node = mbs.AddNode(NodePoint2D(referenceCoordinates=[0.0, 0.0]))
    disk = mbs.AddObject(ObjectMassPoint2D(mass=MASS, nodeNumber=node, name="disk"))

    def shaft(mbs_, t, item, u, v, k, d, offset):
        c, s = math.cos(omega * t), math.sin(omega * t)
        a, b = K_XI * (c * u[0] + s * u[1]), K_ETA * (-s * u[0] + c * u[1])
        return [c * a - s * b + DAMPING * v[0], s * a + c * b + DAMPING * v[1], 0.0]

    mbs.AddObject(ObjectConnectorCartesianSpringDamper(
        markerNumbers=[mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, 0])),
                       mbs.AddMarker(MarkerNodePosition(nodeNumber=node))],
        stiffness=[K_XI, K_ETA, 0.0], damping=[DAMPING, DAMPING, 0.0], springForceUserFunction=shaft, name="shaft"))

    def loads(mbs_, t, load):
        f = MASS * eccentricity * omega ** 2
        return [f * math.cos(omega * t), f * math.sin(omega * t) - MASS * GRAVITY, 0.0]

    mbs.AddLoad(LoadForceVector(markerNumber=mbs.AddMarker(MarkerNodePosition(nodeNumber=node)),
                                loadVector=[0, 0, 0], loadVectorUserFunction=loads))
    return []
