"""Built-in model file: the paper's single-link flexible manipulator (``--model single-link``).

A rigid hub (``NodeRigidBody2D`` + ``ObjectRigidBody2D`` with inertia ``J1``)
held at O by two coordinate constraints; ``elements`` ``ANCFCable2D`` elements
along the x-axis (the reference configuration) clamped to the hub by an
``ObjectJointGeneric`` (position and slope angle of the root node follow the
hub); the tip mass ``m_E`` as an ``ObjectMassPoint2D``; gravity ``-g e_y`` on
the beam and tip mass; the joint damping ``alpha`` as a
``CoordinateSpringDamper`` on the hub angle.  Physical data from
:class:`~mbs_models.parameters.ManipulatorParameters` (default: Table 1).

One drive, ``"hub"``: the hub angle (ODE2 coordinate 2 of the hub node,
reference 0, so ``q_a`` is the absolute angle from the x-axis) follows the
fundamental motion ``q_a^R(t) = mean_angle + amplitude sin(omega t)``
(paper: pi/2 + pi/2 sin(omega t); ``q_a = pi/2`` is the link pointing up).
The initial state is the undeformed link on the rigid motion at ``t = 0``.

``--model exudyn`` is this model with the configured manipulator.  The same model
is built by hand in hub-frame coordinates in the test suite's oracle
(``tests/_link_oracle``), an independent check of this generic path
(``tests/test_model_file.py``).
"""
from __future__ import annotations

import math

import numpy as np
from exudyn.beams import GenerateBeamElementsAlongLine
from exudyn.itemInterface import (CoordinateConstraint, CoordinateSpringDamper, LoadMassProportional,
                                  MarkerBodyMass, MarkerNodeCoordinate, MarkerNodeRigid, NodePointGround,
                                  NodeRigidBody2D, ObjectANCFCable2D, ObjectJointGeneric, ObjectMassPoint2D,
                                  ObjectRigidBody2D)

from mbs_models.damping import material_damping_values
from mbs_models.parameters import ManipulatorParameters

#: Mass of the hub body: the hub centre is held at O by constraints, so its mass
#: never enters the dynamics; Exudyn needs it > 0.
HUB_PLACEHOLDER_MASS = 1.0


def build(mbs, omega, elements=8, params=None, bending_damping=0.0, axial_damping=0.0,
          mean_angle=0.5 * math.pi, amplitude=0.5 * math.pi, gravity=True, material_damping=0.0):
    """Add the single link to ``mbs``; return its hub drive.

    Parameters
    ----------
    mbs : exudyn.MainSystem
    omega : float
        Omega of the fundamental motion (rad/s).
    elements : int
        ANCF elements (>= 1).
    params : ManipulatorParameters or mapping, optional
        Physical data (default Table 1).
    bending_damping, axial_damping : float
        Structural damping of the ANCF elements (Exudyn's ``bendingDamping``,
        ``axialDamping``); default 0 (the paper's link is undamped).
    mean_angle, amplitude : float
        Fundamental motion of the hub.
    gravity : bool
    material_damping : float
        Kelvin-Voigt loss time ``beta`` in s (``--damping``, :mod:`mbs_models.damping`): adds
        ``beta EI`` to ``bendingDamping`` and ``beta EA`` to ``axialDamping``.
    """
    if params is None:
        params = ManipulatorParameters()
    elif not isinstance(params, ManipulatorParameters):
        params = ManipulatorParameters.from_mapping(params)
    if isinstance(elements, bool) or int(elements) != elements or elements < 1:
        raise ValueError(f"elements must be a positive integer, got {elements!r}")
    n_el = int(elements)
    p = params

    ground = mbs.AddNode(NodePointGround())
    m_ground = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))

    th0 = mean_angle
    w0 = amplitude * omega
    hub = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0.0, 0.0, 0.0], initialCoordinates=[0.0, 0.0, th0],
                                      initialVelocities=[0.0, 0.0, w0], name="hub"))
    mbs.AddObject(ObjectRigidBody2D(mass=HUB_PLACEHOLDER_MASS, inertia=p.hub_inertia, nodeNumber=hub, name="hub"))
    hub_markers = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=hub, coordinate=c)) for c in range(3)]
    for c in range(2):  # hub centre fixed at O
        mbs.AddObject(CoordinateConstraint(markerNumbers=[m_ground, hub_markers[c]]))

    bending_damping, axial_damping = material_damping_values(material_damping, p.bending_stiffness,
                                                             p.axial_stiffness, bending_damping, axial_damping)
    template = ObjectANCFCable2D(massPerLength=p.mass_per_length, bendingStiffness=p.bending_stiffness,
                                 axialStiffness=p.axial_stiffness, bendingDamping=float(bending_damping),
                                 axialDamping=float(axial_damping))
    beam = GenerateBeamElementsAlongLine(mbs, [0.0, 0.0, 0.0], [p.length, 0.0, 0.0], n_el, template)
    nodes = list(beam["nodes"])
    elements_ = list(beam["elements"])
    for k, e in enumerate(elements_):
        mbs.SetObjectParameter(e, "name", f"link {k}")
    # initial state: the undeformed link rotated to th0, rotating at w0 (displacements from the reference)
    c, s = math.cos(th0), math.sin(th0)
    for j, node in enumerate(nodes):
        x = j * p.length / n_el
        pos = np.array([c * x, s * x])
        slope = np.array([c, s])
        vel = w0 * np.array([-s * x, c * x])
        slope_t = w0 * np.array([-s, c])
        mbs.SetNodeParameter(node, "initialCoordinates", [pos[0] - x, pos[1], slope[0] - 1.0, slope[1]])
        mbs.SetNodeParameter(node, "initialVelocities", [vel[0], vel[1], slope_t[0], slope_t[1]])
    tip = mbs.AddObject(ObjectMassPoint2D(mass=p.tip_mass, nodeNumber=nodes[-1], name="tip mass"))

    # clamp: root position and slope angle follow the hub (x, y, rot_z)
    m_hub = mbs.AddMarker(MarkerNodeRigid(nodeNumber=hub))
    m_root = mbs.AddMarker(MarkerNodeRigid(nodeNumber=nodes[0]))
    mbs.AddObject(ObjectJointGeneric(markerNumbers=[m_hub, m_root], constrainedAxes=[1, 1, 0, 0, 0, 1], name="clamp"))

    if gravity and p.gravity > 0.0:
        for body in elements_ + [tip]:
            mb = mbs.AddMarker(MarkerBodyMass(bodyNumber=body))
            mbs.AddLoad(LoadMassProportional(markerNumber=mb, loadVector=[0.0, -p.gravity, 0.0]))
    m_angle = hub_markers[2]
    if p.joint_damping > 0.0:
        mbs.AddObject(CoordinateSpringDamper(markerNumbers=[m_ground, m_angle], damping=p.joint_damping))

    def motion(t):
        sn, cs = math.sin(omega * t), math.cos(omega * t)
        return mean_angle + amplitude * sn, amplitude * omega * cs, -amplitude * omega**2 * sn

    return [{"name": "hub", "markers": (m_ground, m_angle), "motion": motion}]
