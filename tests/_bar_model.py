"""Model-file text of a rigid bar on a revolute joint at O, driven in angle (for the model-file tests).

``EXTRA`` is replaced by lines of ``build`` before its return, ``DRIVES`` by the returned drives.
"""
from __future__ import annotations

import textwrap

HEADER = textwrap.dedent("""
    import math
    from exudyn.itemInterface import *
""")

TEMPLATE = HEADER + textwrap.dedent("""
    def build(mbs, omega):
        g = mbs.AddNode(NodePointGround())
        mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=g, coordinate=0))
        n = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0.5, 0, 0]))
        b = mbs.AddObject(ObjectRigidBody2D(nodeNumber=n, mass=1.0, inertia=0.1, name="bar"))
        ground = mbs.AddObject(ObjectGround())
        mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[
            mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, 0])),
            mbs.AddMarker(MarkerBodyPosition(bodyNumber=b, localPosition=[-0.5, 0, 0]))]))
        ma = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n, coordinate=2))
        EXTRA
        return DRIVES
""")
