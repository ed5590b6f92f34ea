"""Rigid two-link arm (vertical plane) with two drives: shoulder (absolute angle) and elbow (relative).

The two-link arm's data (link lengths, section, density, hub and rotor
inertia, motor and tip mass, joint damping) with rigid links: body 1 is link 1
with the hub inertia, body 2 is link 2 with the motor mass at the elbow, the
rotor inertia and the tip mass.  Both joints move harmonically,
``phi1 = pi/2 + (pi/4) sin(W t)`` (absolute) and ``phi2 - phi1 = (pi/4) sin(W t)``;
with no control the linearisation about this motion has 4 states.  Reference
configuration = the state at t = 0; each drive's motion is the displacement of
its coordinate from there (Exudyn's ODE2 coordinates).
"""
import math


L1, L2 = 0.5, 0.4                        # link lengths (m)
RHO_A = 2700.0 * 4e-4                    # mass per length (kg/m)
J_HUB, J_ROTOR = 5.86e-5, 2e-5           # hub and elbow rotor inertia (kg m^2)
M_MOTOR, M_TIP = 0.2, 0.1                # motor mass at the elbow, tip mass (kg)
G = 9.81
ALPHA = 0.01                             # joint damping (N m s / rad)
MEAN1, AMP1 = 0.5 * math.pi, 0.25 * math.pi
AMP2 = 0.25 * math.pi

# body 1: link 1 (uniform rod) + hub inertia; centre of mass C1 from the shoulder
M1 = RHO_A * L1
C1 = 0.5 * L1
J1 = M1 * L1**2 / 12.0 + J_HUB
# body 2: link 2 + motor (at the elbow) + tip mass (at the tip) + rotor inertia
_m_rod = RHO_A * L2
M2 = _m_rod + M_MOTOR + M_TIP
C2 = (_m_rod * 0.5 * L2 + M_TIP * L2) / M2
J2 = (_m_rod * (L2**2 / 12.0 + (0.5 * L2 - C2) ** 2) + M_MOTOR * C2**2 + M_TIP * (L2 - C2) ** 2 + J_ROTOR)


def motions(omega):
    """Absolute shoulder angle and relative elbow angle with two derivatives, as functions of t."""
    def r1(t):
        s, c = math.sin(omega * t), math.cos(omega * t)
        return MEAN1 + AMP1 * s, AMP1 * omega * c, -AMP1 * omega**2 * s

    def r2(t):
        s, c = math.sin(omega * t), math.cos(omega * t)
        return AMP2 * s, AMP2 * omega * c, -AMP2 * omega**2 * s

    return r1, r2


def build(mbs, omega):
    return _double_pendulum().build_arm(mbs, motions(omega), M1=M1, J1=J1, C1=C1, L1=L1, M2=M2, J2=J2, C2=C2,
                                        alpha=ALPHA)


def _double_pendulum():
    """The sibling model file's generic two-body arm (loaded by path, as model files are)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("double_pendulum", Path(__file__).with_name("double_pendulum.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
