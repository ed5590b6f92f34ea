"""Three carts in a row on springs to each other and to a wall; the middle spring's stiffness pulses,
k2(t) = K2 (1 + EPS cos(omega t)) (a belt or a gear mesh), through a spring user function."""
import math

from exudyn.itemInterface import (CoordinateConstraint, CoordinateSpringDamper, MarkerNodeCoordinate,
                                  NodePoint2D, NodePointGround, ObjectMassPoint2D)

MASSES = (1.0, 1.5, 0.8)
K1, K2, K3, EPS = 400.0, 300.0, 250.0, 0.3
C = 0.4  # each spring's dashpot


def build(mbs, omega):
    ground = mbs.AddNode(NodePointGround())
    wall = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    xs = []
    for i, m in enumerate(MASSES):
        n = mbs.AddNode(NodePoint2D(referenceCoordinates=[float(i + 1), 0.0]))
        mbs.AddObject(ObjectMassPoint2D(mass=m, nodeNumber=n, name=f"cart{i + 1}"))
        xs.append(mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n, coordinate=0)))
        mbs.AddObject(CoordinateConstraint(markerNumbers=[wall, mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n,
                                                                                                  coordinate=1))]))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[wall, xs[0]], stiffness=K1, damping=C))

    def pulsing(mbs_, t, item, u, v, k, d, offset):
        return K2 * (1.0 + EPS * math.cos(omega * t)) * u + C * v

    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[xs[0], xs[1]], stiffness=K2, damping=C,
                                         springForceUserFunction=pulsing))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[xs[1], xs[2]], stiffness=K3, damping=C))
    return []
