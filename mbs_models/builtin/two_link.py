"""Built-in model file: the two-link flexible manipulator (``--model two-link``).

A model file in the sense of the package's contract: :func:`build` adds the
system to an empty Exudyn ``MainSystem`` (it does not call ``Assemble``) and
returns the two drives.  Vertical plane, gravity ``g`` along ``-y``.

Bodies
------
* **Shoulder hub** -- ``NodeRigidBody2D`` + ``ObjectRigidBody2D`` (inertia
  ``J1 = 5.86e-5`` kg m^2, Table 1) whose centre is held at O by two
  ``CoordinateConstraint`` (its mass then never enters the dynamics; Exudyn
  needs one, :data:`HUB_PLACEHOLDER_MASS`).
* **Link 1** -- ``l1 = 0.5`` m of ``ObjectANCFCable2D`` (Table 1 section and
  material) generated with ``GenerateBeamElementsAlongLine``; its first node is
  clamped to the hub by an ``ObjectJointGeneric`` on two ``MarkerNodeRigid``
  (position and slope angle).
* **Elbow housing** -- a ``NodeRigidBody2D`` clamped (``ObjectJointGeneric``,
  position and rotation, as the hub clamp) to the last node of link 1, with
  zero inertia (the motor is a point mass).
* **Elbow rotor** -- a ``NodeRigidBody2D`` (inertia ``2e-5`` kg m^2) joined to
  the housing by a revolute joint (``ObjectJointGeneric`` constraining the
  position only).  The motor mass 0.2 kg is split between housing and rotor
  (:data:`ROTOR_MASS_SHARE`): the joint makes their centres coincide, so only
  the sum is physical, and no translational coordinate is massless (a
  singular mass matrix would trouble solvers that invert it).
* **Link 2** -- ``l2 = 0.4`` m of the same cable, clamped to the rotor, with the
  tip mass ``m_E = 0.1`` kg (``ObjectMassPoint2D``) on its last node.
* Joint damping ``alpha = 0.01`` N m s/rad at both joints
  (``CoordinateSpringDamper`` on the two drive coordinates).

Why a housing node (how a *relative* joint angle becomes ``q[m1] - q[m0]``)
--------------------------------------------------------------------------
The contract reads a drive coordinate as ``q[m1] - q[m0]`` of two
``MarkerNodeCoordinate``.  The elbow angle is relative to link 1's end, whose
slope angle is not a node coordinate of an ANCF cable (its nodes carry the
slope vector ``r'``, not an angle).  The housing node turns that angle into a
coordinate: its rotation coordinate equals the absolute slope angle of link
1's end (clamp), the rotor's rotation coordinate is the rotor's absolute
angle, and the elbow angle is their difference.  All rigid nodes have
reference rotation 0, so Exudyn's rotation coordinates (displacements from the
reference) *are* the absolute angles:

* shoulder drive: markers ``(ground coordinate, hub rotation)``,
  ``q1 = theta_hub``, motion ``q1^R = pi/2 + (pi/4) sin(Omega t)``;
* elbow drive: markers ``(housing rotation, rotor rotation)``,
  ``q2 = theta_rotor - theta_housing``, motion ``q2^R = (pi/4) sin(Omega t)``.

The reference configuration is the straight arm along +x; the initial
coordinates and velocities are the rigid fundamental motion at ``t = 0``
(``q1 = pi/2``, ``q2 = 0``: arm straight up, turning with ``q1' = q2' = pi Omega / 4``),
the guess of the periodic orbit.

Options (keyword arguments of :func:`build`, the noise factors of the robust
design among them): ``elements`` per link, ``tip_mass``, ``youngs_modulus``,
``joint_damping``, ``bending_damping``, ``axial_damping``, ``gravity``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from exudyn.beams import GenerateBeamElementsAlongLine
from exudyn.itemInterface import (
    CoordinateConstraint,
    CoordinateSpringDamper,
    LoadMassProportional,
    MarkerBodyMass,
    MarkerNodeCoordinate,
    MarkerNodeRigid,
    NodePointGround,
    NodeRigidBody2D,
    ObjectANCFCable2D,
    ObjectGround,
    ObjectJointGeneric,
    ObjectMassPoint2D,
    ObjectRigidBody2D,
)

from mbs_models.damping import material_damping_values

__all__ = ["TwoLinkParameters", "HarmonicMotion", "build", "DEFAULT_ELEMENTS", "NODE_NAMES"]

#: Default ANCF elements per link.  Two cubic elements per link already give the
#: locked-arm frequencies to 9e-6 (f1) and 5e-4 (f2) against Euler-Bernoulli; the
#: dominant (drive-mode) multipliers change by less than the propagator error
#: between 2, 4 and 8 elements (docs/two-link.md), while the cost of the Floquet
#: product grows with the cube of the size and the axial frequencies with the mesh.
DEFAULT_ELEMENTS = 2

#: The hub centre is held at O, so its mass never enters the dynamics; Exudyn needs one.
HUB_PLACEHOLDER_MASS = 1.0

#: Fraction of the motor mass carried by the rotor body (the rest by the housing);
#: both sit at the elbow, so the split does not change the dynamics.
ROTOR_MASS_SHARE = 0.5

#: Names given to the nodes (the mode labels of the generic path read them).
NODE_NAMES = ("hub", "link1", "elbow_housing", "elbow_rotor", "link2")


@dataclass(frozen=True)
class TwoLinkParameters:
    """Data of the two-link arm (SI units); defaults are the arm's design values.

    Link section and material are Table 1 of the reference paper (both links).
    """

    length1: float = 0.5
    length2: float = 0.4
    area: float = 4e-4
    density: float = 2700.0
    second_moment: float = 1.3333e-8
    youngs_modulus: float = 7.11e10
    hub_inertia: float = 5.86e-5
    motor_mass: float = 0.2
    rotor_inertia: float = 2e-5
    tip_mass: float = 0.1
    joint_damping: float = 0.01
    gravity: float = 9.81
    shoulder_mean: float = 0.5 * math.pi
    shoulder_amplitude: float = 0.25 * math.pi
    elbow_mean: float = 0.0
    elbow_amplitude: float = 0.25 * math.pi

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"two-link parameter {name} must be a finite number, got {value!r}")
        for name in ("length1", "length2", "area", "density", "second_moment", "youngs_modulus",
                     "hub_inertia", "rotor_inertia"):
            if getattr(self, name) <= 0:
                raise ValueError(f"two-link parameter {name} must be > 0, got {getattr(self, name)!r}")
        for name in ("motor_mass", "tip_mass", "joint_damping", "gravity"):
            if getattr(self, name) < 0:
                raise ValueError(f"two-link parameter {name} must be >= 0, got {getattr(self, name)!r}")

    @property
    def mass_per_length(self) -> float:
        """``rho A`` in kg/m."""
        return self.density * self.area


@dataclass(frozen=True)
class HarmonicMotion:
    """``t -> (q, q_t, q_tt)`` of ``q(t) = mean + amplitude sin(omega t)`` (picklable)."""

    mean: float
    amplitude: float
    omega: float

    def __call__(self, t: float) -> tuple[float, float, float]:
        s, c = math.sin(self.omega * t), math.cos(self.omega * t)
        return (
            self.mean + self.amplitude * s,
            self.amplitude * self.omega * c,
            -self.amplitude * self.omega**2 * s,
        )


def _rotate(phi: float, v: np.ndarray) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _cross(w: float, v: np.ndarray) -> np.ndarray:
    """``w e_z x v`` in the plane."""
    return np.array([-w * v[1], w * v[0]])


def build(
    mbs: Any,
    omega: float,
    *,
    elements: int = DEFAULT_ELEMENTS,
    tip_mass: float | None = None,
    youngs_modulus: float | None = None,
    joint_damping: float | None = None,
    bending_damping: float = 0.0,
    axial_damping: float = 0.0,
    gravity: float | None = None,
    parameters: TwoLinkParameters | None = None,
    material_damping: float = 0.0,
) -> list[dict]:
    """Add the two-link flexible arm to ``mbs`` and return its two drives.

    Parameters
    ----------
    mbs : exudyn.MainSystem
        An empty system (``Assemble`` is not called here).
    omega : float
        ``Omega`` of the fundamental motion in rad/s (> 0).
    elements : int
        ANCF elements per link (>= 1).
    tip_mass, youngs_modulus, joint_damping, gravity : float, optional
        Override the corresponding fields of ``parameters`` (the noise factors
        of the robust design are tip mass and ``E``); ``None`` keeps them.
    bending_damping, axial_damping : float
        Structural damping of the cables (Exudyn's ``bendingDamping``,
        ``axialDamping``), default 0 (undamped beams, as in the paper).
    parameters : TwoLinkParameters, optional
        All other data (default: the arm's design values).
    material_damping : float
        Kelvin-Voigt loss time ``beta`` in s (``--damping``, :mod:`mbs_models.damping`): adds
        ``beta EI`` to ``bendingDamping`` and ``beta EA`` to ``axialDamping`` of both links.

    Returns
    -------
    list of dict
        ``[{"name": "shoulder", "markers": (m0, m1), "motion": ...},
        {"name": "elbow", ...}]``, see the module docstring.

    Raises
    ------
    ValueError
        On a non-positive frequency or element count or invalid data.
    """
    if isinstance(omega, bool) or not isinstance(omega, (int, float)) or not math.isfinite(omega) or omega <= 0:
        raise ValueError(f"omega must be finite and > 0, got {omega!r}")
    if isinstance(elements, bool) or int(elements) != elements or elements < 1:
        raise ValueError(f"elements must be a positive integer, got {elements!r}")
    elements = int(elements)
    base = parameters if parameters is not None else TwoLinkParameters()
    if not isinstance(base, TwoLinkParameters):
        raise ValueError(f"parameters must be TwoLinkParameters, got {type(base).__name__}")
    overrides = {"tip_mass": tip_mass, "youngs_modulus": youngs_modulus,
                 "joint_damping": joint_damping, "gravity": gravity}
    p = TwoLinkParameters(**{**base.__dict__, **{k: v for k, v in overrides.items() if v is not None}})
    for name, v in (("bending_damping", bending_damping), ("axial_damping", axial_damping)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    l1, l2 = p.length1, p.length2
    shoulder = HarmonicMotion(p.shoulder_mean, p.shoulder_amplitude, float(omega))
    elbow = HarmonicMotion(p.elbow_mean, p.elbow_amplitude, float(omega))

    # rigid fundamental motion at t = 0: the initial state (orbit guess)
    q1, w1, _ = shoulder(0.0)
    q2, w2, _ = elbow(0.0)
    th2, w_abs2 = q1 + q2, w1 + w2  # absolute angle and rate of link 2
    elbow_ref = np.array([l1, 0.0])
    elbow_pos = _rotate(q1, elbow_ref)
    elbow_vel = _cross(w1, elbow_pos)

    def rigid_state_link1(x_ref: np.ndarray):
        r = _rotate(q1, x_ref)
        return r, _cross(w1, r)

    def rigid_state_link2(x_ref: np.ndarray):
        d = _rotate(th2, x_ref - elbow_ref)
        return elbow_pos + d, elbow_vel + _cross(w_abs2, d)

    ground = mbs.AddObject(ObjectGround())
    ground_node = mbs.AddNode(NodePointGround())
    m_ground = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground_node, coordinate=0))

    def rigid_node(name: str, ref: np.ndarray, pos: np.ndarray, vel: np.ndarray, angle: float, rate: float) -> int:
        return mbs.AddNode(
            NodeRigidBody2D(
                name=name,
                referenceCoordinates=[float(ref[0]), float(ref[1]), 0.0],
                initialCoordinates=[float(pos[0] - ref[0]), float(pos[1] - ref[1]), float(angle)],
                initialVelocities=[float(vel[0]), float(vel[1]), float(rate)],
            )
        )

    # shoulder hub, centre held at O
    hub = rigid_node("hub", np.zeros(2), np.zeros(2), np.zeros(2), q1, w1)
    mbs.AddObject(ObjectRigidBody2D(name="hub_body", mass=HUB_PLACEHOLDER_MASS, inertia=p.hub_inertia, nodeNumber=hub))
    hub_coord = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=hub, coordinate=c)) for c in range(3)]
    for c in range(2):
        mbs.AddObject(CoordinateConstraint(markerNumbers=[m_ground, hub_coord[c]]))

    bending_damping, axial_damping = material_damping_values(
        material_damping, p.youngs_modulus * p.second_moment, p.youngs_modulus * p.area, bending_damping, axial_damping)
    template = ObjectANCFCable2D(
        massPerLength=p.mass_per_length,
        bendingStiffness=p.youngs_modulus * p.second_moment,
        axialStiffness=p.youngs_modulus * p.area,
        bendingDamping=float(bending_damping),
        axialDamping=float(axial_damping),
    )

    def beam(name: str, start: np.ndarray, end: np.ndarray, angle: float, rate: float, state) -> tuple[list, list]:
        data = GenerateBeamElementsAlongLine(mbs, [start[0], start[1], 0.0], [end[0], end[1], 0.0], elements, template)
        nodes, elems = list(data["nodes"]), list(data["elements"])
        slope = _rotate(angle, np.array([1.0, 0.0]))
        slope_t = _cross(rate, slope)
        for k, n in enumerate(nodes):
            ref = np.asarray(mbs.GetNodeParameter(n, "referenceCoordinates"), dtype=float)
            pos, vel = state(ref[:2])
            mbs.SetNodeParameter(n, "name", f"{name}_node{k}")
            mbs.SetNodeParameter(n, "initialCoordinates",
                                 [pos[0] - ref[0], pos[1] - ref[1], slope[0] - ref[2], slope[1] - ref[3]])
            mbs.SetNodeParameter(n, "initialVelocities", [vel[0], vel[1], slope_t[0], slope_t[1]])
        for k, e in enumerate(elems):
            mbs.SetObjectParameter(e, "name", f"{name}_element{k}")
        return nodes, elems

    def clamp(node_a: int, node_b: int, rotation: bool = True) -> None:
        ma = mbs.AddMarker(MarkerNodeRigid(nodeNumber=node_a))
        mb = mbs.AddMarker(MarkerNodeRigid(nodeNumber=node_b))
        mbs.AddObject(ObjectJointGeneric(markerNumbers=[ma, mb], constrainedAxes=[1, 1, 0, 0, 0, int(rotation)]))

    nodes1, elems1 = beam("link1", np.zeros(2), elbow_ref, q1, w1, rigid_state_link1)
    clamp(hub, nodes1[0])

    # elbow: housing (motor mass) clamped to link 1's end, rotor on a revolute joint
    housing = rigid_node("elbow_housing", elbow_ref, elbow_pos, elbow_vel, q1, w1)
    housing_body = mbs.AddObject(ObjectRigidBody2D(name="elbow_housing_body", mass=(1 - ROTOR_MASS_SHARE) * p.motor_mass,
                                                   inertia=0.0,
                                                   nodeNumber=housing))
    clamp(nodes1[-1], housing)
    rotor = rigid_node("elbow_rotor", elbow_ref, elbow_pos, elbow_vel, th2, w_abs2)
    rotor_body = mbs.AddObject(ObjectRigidBody2D(name="elbow_rotor_body", mass=ROTOR_MASS_SHARE * p.motor_mass,
                                                 inertia=p.rotor_inertia, nodeNumber=rotor))
    clamp(housing, rotor, rotation=False)

    nodes2, elems2 = beam("link2", elbow_ref, np.array([l1 + l2, 0.0]), th2, w_abs2, rigid_state_link2)
    clamp(rotor, nodes2[0])
    tip = mbs.AddObject(ObjectMassPoint2D(name="tip_mass", mass=p.tip_mass, nodeNumber=nodes2[-1]))

    if p.gravity > 0.0:
        for body in elems1 + elems2 + [housing_body, rotor_body, tip]:
            mb = mbs.AddMarker(MarkerBodyMass(bodyNumber=body))
            mbs.AddLoad(LoadMassProportional(markerNumber=mb, loadVector=[0.0, -p.gravity, 0.0]))

    m_hub_angle = hub_coord[2]
    m_housing_angle = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=housing, coordinate=2))
    m_rotor_angle = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=rotor, coordinate=2))
    if p.joint_damping > 0.0:
        mbs.AddObject(CoordinateSpringDamper(name="shoulder_damper", markerNumbers=[m_ground, m_hub_angle],
                                             damping=p.joint_damping))
        mbs.AddObject(CoordinateSpringDamper(name="elbow_damper", markerNumbers=[m_housing_angle, m_rotor_angle],
                                             damping=p.joint_damping))
    return [
        {"name": "shoulder", "markers": (m_ground, m_hub_angle), "motion": shoulder},
        {"name": "elbow", "markers": (m_housing_angle, m_rotor_angle), "motion": elbow},
    ]
