"""Built-in model file: a Laval (Jeffcott) rotor with an anisotropic shaft (``--model laval-rotor``).

A disk of mass ``m`` (an ``ObjectMassPoint2D`` on a ``NodePoint2D``: the disk's
centre in the plane normal to the shaft, inertial coordinates ``x``, ``y``) sits
at the middle of a massless shaft turning at the constant speed ``omega``.  The
shaft's bending stiffness differs in its two principal directions: ``k_xi``
along the shaft-fixed axis ``e_xi = (cos omega t, sin omega t)`` and ``k_eta``
across it.  The restoring force on the disk, written in the inertial frame, is

    f = -R(omega t) diag(k_xi, k_eta) R(omega t)^T u - c u',

with ``u = (x, y)`` the disk's displacement from the bearing axis, ``R`` the
rotation by the shaft angle and ``c`` an external (non-rotating) viscous damping.
It is an ``ObjectConnectorCartesianSpringDamper`` between the ground and the
disk whose ``springForceUserFunction`` evaluates that force (the shaft angle
``omega t`` enters as time, so the model needs no drive and its coefficients are
periodic with period ``pi / omega``, hence ``T = 2 pi / omega``-periodic).
Gravity ``-g e_y`` (a horizontal shaft) makes the orbit a non-trivial forced
periodic motion (the static sag modulated at twice the shaft speed); the
linearisation about it does not depend on it (the model is linear).

In the shaft-fixed frame the equations have constant coefficients
(centrifugal ``-m omega^2``, Coriolis ``2 m omega J`` and the damping's
``c omega J``), so the multipliers over one turn are known exactly; undamped,
the rotor is unstable for ``omega`` between ``sqrt(k_xi/m)`` and ``sqrt(k_eta/m)``
(the classical result for an asymmetric shaft, e.g. Genta, *Dynamics of Rotating
Systems*, Sec. 4.8; Kraemer, *Dynamics of Rotors and Foundations*, Ch. 13).
The tests compare the package's multipliers with that closed form.

Default data: ``m = 2 kg``, ``k_xi = 2.0e4 N/m``, ``k_eta = 2.6e4 N/m`` (shaft
frequencies 100 rad/s and 114.0 rad/s), ``c = 2 N s/m`` (about 0.5 % of
critical), ``g = 9.81 m/s^2``.
"""
from __future__ import annotations

import math

from exudyn.itemInterface import (LoadMassProportional, MarkerBodyMass, MarkerBodyPosition, MarkerNodePosition,
                                  NodePoint2D, ObjectConnectorCartesianSpringDamper, ObjectGround,
                                  ObjectMassPoint2D)

#: Default disk mass (kg), shaft stiffnesses (N/m), external damping (N s/m), gravity (m/s^2).
DEFAULTS = {"mass": 2.0, "stiffness_xi": 2.0e4, "stiffness_eta": 2.6e4, "damping": 2.0, "gravity": 9.81}
#: x of the bearing axis (m); see the comment in :func:`build`.
BEARING_X = 1.0


def _positive(name: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def _non_negative(name: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return v


def build(mbs, omega, mass=DEFAULTS["mass"], stiffness_xi=DEFAULTS["stiffness_xi"],
          stiffness_eta=DEFAULTS["stiffness_eta"], damping=DEFAULTS["damping"], gravity=DEFAULTS["gravity"]):
    """Add the rotor to ``mbs``; it has no drives (the shaft speed is a parameter).

    Parameters
    ----------
    mbs : exudyn.MainSystem
    omega : float
        Shaft speed (rad/s).
    mass : float
        Disk mass (kg).
    stiffness_xi, stiffness_eta : float
        Shaft stiffness along / across its shaft-fixed principal axis ``e_xi`` (N/m).
    damping : float
        External viscous damping on the disk (N s/m).
    gravity : float
        Gravity along ``-y`` (m/s^2); 0 for a vertical shaft.
    """
    m = _positive("mass", mass)
    k_xi = _positive("stiffness_xi", stiffness_xi)
    k_eta = _positive("stiffness_eta", stiffness_eta)
    c = _non_negative("damping", damping)
    g = _non_negative("gravity", gravity)
    w = float(omega)

    ground = mbs.AddObject(ObjectGround())
    # initial guess of the orbit: the static sag of the mean stiffness
    sag = -m * g * 0.5 * (1.0 / k_xi + 1.0 / k_eta)
    # the bearing axis passes through (BEARING_X, 0): free planar points co-rotate with their best-fit rotation
    # about the origin (linearize.constrained.corotating_frame) where the samples resolve it, and off the
    # origin it stays small; a bearing on the origin works too (tests/models/unbalanced_rotor.py)
    disk_node = mbs.AddNode(NodePoint2D(referenceCoordinates=[BEARING_X, 0.0], initialCoordinates=[0.0, sag],
                                        name="disk"))
    disk = mbs.AddObject(ObjectMassPoint2D(mass=m, nodeNumber=disk_node, name="disk"))

    def shaft_force(mbs_, t, item, u, v, k, d, offset):  # noqa: ARG001 - Exudyn's signature
        # force of the rotating anisotropic shaft (+ external damping), Exudyn's sign: the
        # connector applies -f to the disk, so f = K(t) u + c u' is the restoring force
        cs, sn = math.cos(w * t), math.sin(w * t)
        a = cs * u[0] + sn * u[1]  # displacement along e_xi
        b = -sn * u[0] + cs * u[1]  # along e_eta
        fa, fb = k_xi * a, k_eta * b
        return [cs * fa - sn * fb + c * v[0], sn * fa + cs * fb + c * v[1], 0.0]

    m_ground = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[BEARING_X, 0.0, 0.0]))
    m_disk = mbs.AddMarker(MarkerNodePosition(nodeNumber=disk_node))
    mbs.AddObject(ObjectConnectorCartesianSpringDamper(markerNumbers=[m_ground, m_disk], stiffness=[k_xi, k_eta, 0.0],
                                                       damping=[c, c, 0.0], springForceUserFunction=shaft_force,
                                                       name="shaft"))
    if g > 0.0:
        mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=disk)),
                                         loadVector=[0.0, -g, 0.0]))
    return []
