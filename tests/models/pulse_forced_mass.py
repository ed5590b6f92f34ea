"""A point mass on an (x-)inverted spring with a strong dashpot, forced by a periodic load
F cos(omega t + phi): NOT autonomous (the load depends on time). Multipliers exp(lambda T),
lambda^2 + c lambda - a = 0 (x), plus a damped pair in y and z."""
import math
from exudyn.itemInterface import (CartesianSpringDamper, LoadForceVector, MarkerBodyPosition, MarkerNodePosition,
                                  MassPoint, NodePoint, ObjectGround)

A, C, F = 0.1, 5.0, 1.0


def build(mbs, omega, phi=0.15 * math.pi, pulse=False):
    ground = mbs.AddObject(ObjectGround())
    n = mbs.AddNode(NodePoint(referenceCoordinates=[0, 0, 0]))
    mbs.AddObject(MassPoint(nodeNumber=n, physicsMass=1.0, name="mass"))
    mg = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, 0]))
    mn = mbs.AddMarker(MarkerNodePosition(nodeNumber=n))
    mbs.AddObject(CartesianSpringDamper(markerNumbers=[mg, mn], stiffness=[-A, 40.0, 40.0], damping=[C, 1.0, 1.0]))

    def load(mbs_, t, v):
        if pulse:  # a periodic smooth hammer blow, 0.3 T long, centred on t = 0 mod T
            s = ((omega * t / (2 * math.pi) + 0.5) % 1.0 - 0.5) / 0.15
            return [F * math.exp(1.0 - 1.0 / (1.0 - s * s)) if abs(s) < 1.0 else 0.0, 0.0, 0.0]
        return [F * math.cos(omega * t + phi), 0.0, 0.0]

    mbs.AddLoad(LoadForceVector(markerNumber=mn, loadVector=[0, 0, 0], loadVectorUserFunction=load))
    return []
