"""Chain of three masses in the plane joined by ``CartesianSpringDamper``s, one stiffness periodic.

Ground -- m1 -- m2 -- m3 along x.  Each spring has stiffness ``(KX, KY)`` and damping ``(CX, CY)``;
the lateral (y) stiffness of the m2 -- m3 spring varies as ``KY (1 + EPS cos(omega t))`` (a spring
force user function), which pumps the lateral modes.  One drive moves mass 1 along x,
``x1 = A sin(omega t)``.  The lateral modes are decoupled from x in the linearisation: the drive
cannot move them (its share in them is zero), whatever its PD gains.
"""
import math

from exudyn.itemInterface import (CartesianSpringDamper, MarkerBodyPosition, MarkerNodeCoordinate, NodePoint2D,
                                  NodePointGround, ObjectGround, ObjectMassPoint2D)

MASS = 1.0
KX, KY = 400.0, 40.0      # axial and lateral stiffness of each spring (N/m)
CX, CY = 2.0, 0.02        # axial and lateral damping (N s/m)
EPS = 0.3                 # relative modulation of the m2 -- m3 lateral stiffness
AMPLITUDE = 0.01          # drive amplitude (m)


def build(mbs, omega):
    ground = mbs.AddObject(ObjectGround())
    gnode = mbs.AddNode(NodePointGround())
    mg_coord = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gnode, coordinate=0))
    previous = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, 0]))
    coords = []
    for i in range(3):
        n = mbs.AddNode(NodePoint2D(referenceCoordinates=[i + 1.0, 0.0]))
        body = mbs.AddObject(ObjectMassPoint2D(nodeNumber=n, mass=MASS, name=f"m{i + 1}"))
        marker = mbs.AddMarker(MarkerBodyPosition(bodyNumber=body, localPosition=[0, 0, 0]))
        spring = dict(markerNumbers=[previous, marker], stiffness=[KX, KY, 0.0], damping=[CX, CY, 0.0])
        if i == 2:
            def force(mbs_, t, item, u, v, k, d, off):
                ky = KY * (1.0 + EPS * math.cos(omega * t))
                return [KX * u[0] + CX * v[0], ky * u[1] + CY * v[1], 0.0]

            spring["springForceUserFunction"] = force
        mbs.AddObject(CartesianSpringDamper(**spring))
        coords.append(mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n, coordinate=0)))
        previous = marker

    def motion(t):
        s, c = math.sin(omega * t), math.cos(omega * t)
        return AMPLITUDE * s, AMPLITUDE * omega * c, -AMPLITUDE * omega**2 * s

    return [{"name": "drive1", "markers": (mg_coord, coords[0]), "motion": motion}]
