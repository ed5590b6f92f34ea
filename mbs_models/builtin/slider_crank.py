"""Built-in model file: a slider-crank with a flexible connecting rod at constant crank speed (``--model slider-crank``).

A rigid crank of length ``r`` turns about the origin (a ``NodeRigidBody2D`` held at O by two coordinate
constraints, an ``ObjectRigidBody2D`` with inertia ``J_crank``); a connecting rod of length ``l`` made of
``elements`` ``ANCFCable2D`` elements is pinned to the crank pin (``ObjectJointRevolute2D`` between the pin
and the rod's first node) and to a slider of mass ``m_s`` (a mass point on the rod's last node whose ``y``
is held at 0 by a ``CoordinateConstraint``: the slider's guide).  The reference configuration is the
crank along ``+x`` (angle 0) and the rod along ``+x`` from the pin to the slider.  The rod has structural
damping (Exudyn's ``bendingDamping``, ``axialDamping``), gravity is off by default (a horizontal mechanism).

The crank turns at the constant speed ``omega``: one turn per period ``T = 2 pi / omega``.

* ``form="drive"`` (default): the crank angle is a drive with ``motion = (omega t, omega, 0)``; it
  advances by a whole turn per period.  On the orbit the crank follows it exactly; in the closed loop
  it is released under feed-forward + PD (``flexstab tune`` / ``validate``).
* ``form="constraint"``: no drive; the crank angle is held at ``omega t`` by a ``CoordinateConstraint``
  with an offset user function -- the constant-speed crank of the classical problem of elastic
  mechanisms, whose rod is parametrically excited (axial inertia load at ``omega``, ``2 omega``, ...).

Initial state: the rigid mechanism at crank angle 0 moving at ``omega`` (the orbit's guess).

Default data: crank 0.15 m (inertia 1e-3 kg m^2), rod 0.3 m, an aluminium rod of 8 mm diameter
(``mass_per_length`` 0.136 kg/m, ``bending_stiffness`` EI = 14.1 N m^2, ``axial_stiffness`` EA = 3.52e6 N:
first pinned-pinned bending frequency 178 Hz, Euler buckling load 1.5 kN), slider 0.1 kg.  At 150 rad/s
the inertia load on the rod is about a quarter of the buckling load; a heavier slider or a faster crank
buckles the rod (no periodic orbit).  The tests compare the multipliers with a finite-difference monodromy of the nonlinear model
computed from Exudyn runs alone.
"""
from __future__ import annotations

import math

import numpy as np
from exudyn.beams import GenerateBeamElementsAlongLine
from exudyn.itemInterface import (CoordinateConstraint, LoadMassProportional, MarkerBodyMass, MarkerBodyPosition,
                                  MarkerNodeCoordinate, MarkerNodePosition, NodePointGround, NodeRigidBody2D,
                                  ObjectANCFCable2D, ObjectJointRevolute2D, ObjectMassPoint2D, ObjectRigidBody2D)

#: Default data (SI): crank length and inertia, rod length, mass per length, EI, EA, slider mass, damping.
DEFAULTS = {"crank": 0.15, "crank_inertia": 1e-3, "rod": 0.3, "mass_per_length": 0.136,
            "bending_stiffness": 14.1, "axial_stiffness": 3.52e6, "slider_mass": 0.1,
            "bending_damping": 2e-4, "axial_damping": 20.0, "gravity": 0.0}
#: Mass of the crank body: its centre is held at O by constraints, so the mass never enters the dynamics.
CRANK_PLACEHOLDER_MASS = 1.0


def _positive(name, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def _non_negative(name, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return v


def build(mbs, omega, form="drive", elements=2, crank=DEFAULTS["crank"], crank_inertia=DEFAULTS["crank_inertia"],
          rod=DEFAULTS["rod"], mass_per_length=DEFAULTS["mass_per_length"],
          bending_stiffness=DEFAULTS["bending_stiffness"], axial_stiffness=DEFAULTS["axial_stiffness"],
          slider_mass=DEFAULTS["slider_mass"], bending_damping=DEFAULTS["bending_damping"],
          axial_damping=DEFAULTS["axial_damping"], gravity=DEFAULTS["gravity"]):
    """Add the slider-crank to ``mbs``; return the crank drive (``form="drive"``) or no drive.

    Parameters
    ----------
    mbs : exudyn.MainSystem
    omega : float
        Crank speed (rad/s).
    form : {"drive", "constraint"}
    elements : int
        ANCF elements of the rod (>= 1).
    crank, rod : float
        Lengths (m), ``rod > crank``.
    crank_inertia, mass_per_length, bending_stiffness, axial_stiffness, slider_mass : float
        SI units.
    bending_damping, axial_damping : float
        Exudyn's structural damping of the rod elements.
    gravity : float
        Along ``-y`` (m/s^2).
    """
    if form not in ("drive", "constraint"):
        raise ValueError(f"form must be 'drive' or 'constraint', got {form!r}")
    if isinstance(elements, bool) or int(elements) != elements or elements < 1:
        raise ValueError(f"elements must be a positive integer, got {elements!r}")
    r, l = _positive("crank", crank), _positive("rod", rod)
    if not l > r:
        raise ValueError(f"the rod ({l}) must be longer than the crank ({r})")
    J = _positive("crank_inertia", crank_inertia)
    mu = _positive("mass_per_length", mass_per_length)
    EI, EA = _positive("bending_stiffness", bending_stiffness), _positive("axial_stiffness", axial_stiffness)
    ms = _positive("slider_mass", slider_mass)
    db, da = _non_negative("bending_damping", bending_damping), _non_negative("axial_damping", axial_damping)
    g = _non_negative("gravity", gravity)
    w = float(omega)

    ground = mbs.AddNode(NodePointGround())
    m_ground = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    crank_node = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0.0, 0.0, 0.0], initialVelocities=[0.0, 0.0, w],
                                             name="crank"))
    crank_body = mbs.AddObject(ObjectRigidBody2D(nodeNumber=crank_node, mass=CRANK_PLACEHOLDER_MASS, inertia=J,
                                                 name="crank"))
    mc = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=crank_node, coordinate=c)) for c in range(3)]
    for c in range(2):
        mbs.AddObject(CoordinateConstraint(markerNumbers=[m_ground, mc[c]]))

    template = ObjectANCFCable2D(massPerLength=mu, bendingStiffness=EI, axialStiffness=EA, bendingDamping=db,
                                 axialDamping=da)
    beam = GenerateBeamElementsAlongLine(mbs, [r, 0.0, 0.0], [r + l, 0.0, 0.0], int(elements), template)
    nodes, elems = list(beam["nodes"]), list(beam["elements"])
    for k, e in enumerate(elems):
        mbs.SetObjectParameter(e, "name", f"rod {k}")
    # initial velocities of the rigid mechanism at crank angle 0: pin (0, r w), rod angle rate -r w / l
    for j, node in enumerate(nodes):
        s = j * l / len(elems)
        mbs.SetNodeParameter(node, "initialVelocities", [0.0, r * w * (1.0 - s / l), 0.0, -r * w / l])
    slider = mbs.AddObject(ObjectMassPoint2D(mass=ms, nodeNumber=nodes[-1], name="slider"))
    pin = mbs.AddMarker(MarkerBodyPosition(bodyNumber=crank_body, localPosition=[r, 0.0, 0.0]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[pin, mbs.AddMarker(MarkerNodePosition(nodeNumber=nodes[0]))],
                                        name="crank pin"))
    guide = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nodes[-1], coordinate=1))
    mbs.AddObject(CoordinateConstraint(markerNumbers=[m_ground, guide], name="slider guide"))
    if g > 0.0:
        for body in elems + [slider]:
            mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=body)),
                                             loadVector=[0.0, -g, 0.0]))
    if form == "constraint":
        mbs.AddObject(CoordinateConstraint(markerNumbers=[m_ground, mc[2]],
                                           offsetUserFunction=lambda mbs_, t, item, off: w * t, name="crank speed"))
        return []
    return [{"name": "crank", "markers": (m_ground, mc[2]), "motion": lambda t: (w * t, w, 0.0)}]
