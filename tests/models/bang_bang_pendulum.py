"""Pendulum hanging from a support driven vertically with a bang-bang acceleration (no smooth law).

The support's height follows ``r(t)``, piecewise quadratic: acceleration ``-A`` on ``[0, t1)`` and
``[T - t1, T)``, ``+B = 2 A t1 / (T - 2 t1)`` on ``[t1, T - t1)`` (a trapezoid-free, triangular
velocity profile; ``r``, ``r'`` continuous and T-periodic), ``t1 = FRACTION T`` with an irrational
fraction (no equal step count lands on it by accident).  The support's height is the drive; the
pendulum hangs on a revolute joint with a rotational damper ``c``.  About the hanging orbit
(``theta = 0``, support on ``r``) with PD gains ``kp, kd`` on the drive, the linearisation decouples
(hand-derived from the Lagrangian)::

    (m_s + m) y'' + kd y' + kp y = 0
    J_p th'' + c th' + m l (g + r''(t)) th = 0,      J_p = J + m l^2,

and ``r''`` jumps at ``t1`` and ``T - t1``.  ``build(mbs, omega, declare=True)`` declares those times as
the drive's breakpoints; ``declare=False`` leaves them out.
"""
import math

from exudyn.itemInterface import (CoordinateConstraint, CoordinateSpringDamper, LoadMassProportional,
                                  MarkerBodyMass, MarkerBodyPosition, MarkerNodeCoordinate, NodePointGround,
                                  NodeRigidBody2D, ObjectJointRevolute2D, ObjectRigidBody2D)

SUPPORT_MASS = 1.0
MASS = 0.8
INERTIA = 0.01      # about the centre of mass
LENGTH = 0.3        # pivot -> centre of mass
GRAVITY = 9.81
ACCELERATION = 4.0  # A (m/s^2)
DAMPING = 0.02      # rotational damper c


FRACTION = 0.5 * (math.sqrt(2.0) - 1.0)  # t1 / T


def support_motion(omega, acceleration=ACCELERATION):
    """``(t -> (r, r', r''), (t1, T - t1), (A, B))`` of the bang-bang law, T-periodic, ``r(0) = 0``."""
    T = 2.0 * math.pi / omega
    A = acceleration
    t1 = FRACTION * T
    B = 2.0 * A * t1 / (T - 2.0 * t1)
    y1 = -0.5 * A * t1 * t1                       # r(t1)
    y2 = y1 - A * t1 * (T - 2.0 * t1) + 0.5 * B * (T - 2.0 * t1) ** 2   # r(T - t1)

    def r(t):
        x = math.fmod(t, T)
        if x < 0.0:
            x += T
        if x < t1:
            return -0.5 * A * x * x, -A * x, -A
        if x < T - t1:
            u = x - t1
            return y1 - A * t1 * u + 0.5 * B * u * u, -A * t1 + B * u, B
        u = x - (T - t1)
        return y2 + A * t1 * u - 0.5 * A * u * u, A * t1 - A * u, -A

    return r, (t1, T - t1), (A, B)


def build(mbs, omega, declare=True, acceleration=ACCELERATION):
    r, breakpoints, _ = support_motion(omega, acceleration)
    ground = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
    ns = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0, 0, 0], initialCoordinates=[0, r(0.0)[0], 0],
                                     initialVelocities=[0, r(0.0)[1], 0]))
    support = mbs.AddObject(ObjectRigidBody2D(nodeNumber=ns, mass=SUPPORT_MASS, inertia=1.0, name="support"))
    ms = [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ns, coordinate=c)) for c in range(3)]
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, ms[0]]))
    mbs.AddObject(CoordinateConstraint(markerNumbers=[mg, ms[2]]))
    npd = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0, -LENGTH, 0],
                                      initialCoordinates=[0, r(0.0)[0], 0],
                                      initialVelocities=[0, r(0.0)[1], 0]))
    pend = mbs.AddObject(ObjectRigidBody2D(nodeNumber=npd, mass=MASS, inertia=INERTIA, name="pendulum"))
    m_sup = mbs.AddMarker(MarkerBodyPosition(bodyNumber=support, localPosition=[0, 0, 0]))
    m_pen = mbs.AddMarker(MarkerBodyPosition(bodyNumber=pend, localPosition=[0, LENGTH, 0]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[m_sup, m_pen]))
    mp = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=npd, coordinate=2))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[ms[2], mp], stiffness=0.0, damping=DAMPING))
    mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=pend)),
                                     loadVector=[0, -GRAVITY, 0]))
    drive = {"name": "lift", "markers": (mg, ms[1]), "motion": r}
    if declare:
        drive["breakpoints"] = breakpoints
    return [drive]
