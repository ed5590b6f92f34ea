"""The built-in two-link model file, checked standalone in plain Exudyn.

Oracles, all independent of the model file:

* rigid-body mass properties: ``u^T M u`` for a rigid translation / rotation
  about O against the hand-computed total mass and moment of inertia, and the
  generalised gravity forces of a rigid pose against the hand-computed static
  gravity torques at the shoulder and the elbow;
* the natural frequencies of the arm with both joints locked against the
  Euler-Bernoulli characteristic determinant of a clamped two-segment beam
  with the motor mass + rotor inertia at the elbow and the tip mass (written
  here), with the O(h^4) convergence of cubic Hermite elements;
* a short simulation with both drives prescribed (Exudyn's
  ``CoordinateConstraint`` with offset user functions): the tip stays at the
  rigid forward kinematics of ``(q1, q1 + q2)`` within the elastic deflection
  bound, which an absolute elbow angle would violate by decimetres.
"""
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest
from scipy.optimize import brentq

exu = pytest.importorskip("exudyn")
from exudyn.itemInterface import CoordinateConstraint  # noqa: E402

from mbs_models.builtin import two_link  # noqa: E402
from mbs_models.builtin.two_link import TwoLinkParameters, build  # noqa: E402

P = TwoLinkParameters()
L = P.length1 + P.length2
M1, M2 = P.mass_per_length * P.length1, P.mass_per_length * P.length2


def _system(elements=2, lock=False, prescribe=False, **options):
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    drives = build(mbs, 2 * math.pi, elements=elements, **options)
    for d in drives:
        motion = d["motion"]
        if lock:
            mbs.AddObject(CoordinateConstraint(markerNumbers=list(d["markers"]), offset=motion(0.0)[0]))
        if prescribe:
            mbs.AddObject(CoordinateConstraint(
                markerNumbers=list(d["markers"]),
                offsetUserFunction=lambda m, t, i, v, mo=motion: mo(t)[0],
                offsetUserFunction_t=lambda m, t, i, v, mo=motion: mo(t)[1],
            ))
    mbs.Assemble()
    return sc, mbs, drives


def _nodes(mbs):
    """(index, name, type, ODE2 start index, reference coordinates) of every node with coordinates."""
    out = []
    for n in range(mbs.systemData.NumberOfNodes()):
        node = mbs.GetNode(n)
        if node["nodeType"] == "PointGround":
            continue
        out.append((n, node["name"], node["nodeType"], mbs.GetNodeODE2Index(n),
                    np.asarray(node["referenceCoordinates"], dtype=float)))
    return out


def _rigid_pose(mbs, q1, q2):
    """ODE2 coordinates of the undeformed arm at shoulder q1 and elbow q2, and the
    rigid-rotation vectors u1 = dq/dq1 (whole arm about O) and u2 = dq/dq2 (link 2 about the elbow)."""
    n = mbs.systemData.ODE2Size()
    q, u1, u2 = np.zeros(n), np.zeros(n), np.zeros(n)

    def rot(phi, v):
        c, s = math.cos(phi), math.sin(phi)
        return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])

    def perp(v):
        return np.array([-v[1], v[0]])

    elbow = rot(q1, np.array([P.length1, 0.0]))
    for _, name, kind, i, ref in _nodes(mbs):
        on_link2 = name.startswith("link2") or name == "elbow_rotor"
        angle = q1 + q2 if on_link2 else q1
        pos = elbow + rot(angle, ref[:2] - [P.length1, 0.0]) if on_link2 else rot(q1, ref[:2])
        q[i:i + 2] = pos - ref[:2]
        u1[i:i + 2] = perp(pos)
        if on_link2:
            u2[i:i + 2] = perp(pos - elbow)
        if kind == "RigidBody2D":
            q[i + 2] = angle
            u1[i + 2] = 1.0
            u2[i + 2] = 1.0 if on_link2 else 0.0
        else:  # ANCF slope vector
            slope = rot(angle, np.array([1.0, 0.0]))
            q[i + 2:i + 4] = slope - ref[2:4]
            u1[i + 2:i + 4] = perp(slope)
            if on_link2:
                u2[i + 2:i + 4] = perp(slope)
    return q, u1, u2


def _solver(mbs):
    s = exu.MainSolverImplicitSecondOrder()
    settings = exu.SimulationSettings()
    settings.linearSolver.solverType = exu.LinearSolverType.EigenDense
    settings.solution.file.write = False  # no solution/ folder in the working directory
    s.InitializeSolver(mbs, settings)
    return s


def test_rigid_mass_properties_against_hand_calculation():
    _, mbs, _ = _system(elements=2)
    s = _solver(mbs)
    s.ComputeMassMatrix(mbs)
    M = np.array(s.GetSystemMassMatrix())
    q, u1, u2 = _rigid_pose(mbs, 0.3, 0.7)
    ux = np.zeros(mbs.systemData.ODE2Size())
    for _, _, kind, i, _ in _nodes(mbs):
        ux[i] = 1.0
    total = two_link.HUB_PLACEHOLDER_MASS + M1 + P.motor_mass + M2 + P.tip_mass
    # cubic Hermite shape functions reproduce rigid motion exactly: round-off only
    assert ux @ M @ ux == pytest.approx(total, rel=1e-12)
    l1, l2, c2 = P.length1, P.length2, math.cos(0.7)
    # bent arm (q2 = 0.7) about O: |r|^2 = l1^2 + s^2 + 2 l1 s cos q2 along link 2
    j_shoulder = (P.hub_inertia + M1 * l1**2 / 3 + P.motor_mass * l1**2 + P.rotor_inertia
                  + P.mass_per_length * (l1**2 * l2 + l1 * l2**2 * c2 + l2**3 / 3)
                  + P.tip_mass * (l1**2 + l2**2 + 2 * l1 * l2 * c2))
    assert u1 @ M @ u1 == pytest.approx(j_shoulder, rel=1e-12)
    j_elbow = P.rotor_inertia + M2 * P.length2**2 / 3 + P.tip_mass * P.length2**2
    assert u2 @ M @ u2 == pytest.approx(j_elbow, rel=1e-12)
    # a wrong answer is rejected: without the rotor the shoulder inertia is off by far more than round-off
    assert abs(u1 @ M @ u1 - (j_shoulder - P.rotor_inertia)) > 1e-6 * j_shoulder


def test_static_gravity_torques_against_hand_calculation():
    _, mbs, _ = _system(elements=2)
    s = _solver(mbs)
    q1, q2 = 0.3, 0.7
    q, u1, u2 = _rigid_pose(mbs, q1, q2)
    sd = mbs.systemData
    cur = exu.ConfigurationType.Current
    sd.SetODE2Coordinates(q, configuration=cur)
    sd.SetODE2Coordinates_t(np.zeros_like(q), configuration=cur)
    s.ComputeODE2RHS(mbs)
    f = np.array(s.GetSystemResidual())[: sd.ODE2Size()]
    g = P.gravity
    c1, c12 = math.cos(q1), math.cos(q1 + q2)
    # torques of the weights about O and about the elbow (hand calculation, rigid arm)
    tau_elbow = -g * (M2 * P.length2 / 2 + P.tip_mass * P.length2) * c12
    tau_shoulder = -g * ((M1 / 2 + P.motor_mass + M2 + P.tip_mass) * P.length1 * c1) + tau_elbow
    # undeformed pose: elastic forces vanish exactly; the sums are O(10) round-off terms
    assert u1 @ f == pytest.approx(tau_shoulder, rel=1e-10)
    assert u2 @ f == pytest.approx(tau_elbow, rel=1e-10)
    # rejects a motor weight left out
    assert abs(u1 @ f - (tau_shoulder + g * P.motor_mass * P.length1 * c1)) > 0.1


def _determinant(b, rotor_inertia=P.rotor_inertia):
    """Euler-Bernoulli frequency determinant of the locked arm at wavenumber b (1/m).

    Clamped at O; at x = l1 continuity of w, w' and the jumps
    EI (w1'' - w2'') = J w^2 w' (rotor inertia), EI (w2''' - w1''') = m w^2 w (motor mass);
    at the tip EI w'' = 0 and EI w''' = -m_E w^2 w (virtual work of T - V).
    """
    EI = P.youngs_modulus * P.second_moment
    w2 = b**4 * EI / P.mass_per_length

    def basis(x):
        c, s, ch, sh = math.cos(b * x), math.sin(b * x), math.cosh(b * x), math.sinh(b * x)
        return np.array([[c, s, ch, sh], [-b * s, b * c, b * sh, b * ch],
                         [-b * b * c, -b * b * s, b * b * ch, b * b * sh],
                         [b**3 * s, -b**3 * c, b**3 * sh, b**3 * ch]])

    A = np.zeros((8, 8))
    B0, B1, Bl = basis(0.0), basis(P.length1), basis(P.length2)
    A[0, :4], A[1, :4] = B0[0], B0[1]
    A[2, :4], A[2, 4:] = B1[0], -B0[0]
    A[3, :4], A[3, 4:] = B1[1], -B0[1]
    A[4, :4], A[4, 4:] = EI * B1[2] - rotor_inertia * w2 * B1[1], -EI * B0[2]
    A[5, :4], A[5, 4:] = -EI * B1[3] - P.motor_mass * w2 * B1[0], EI * B0[3]
    A[6, 4:] = Bl[2]
    A[7, 4:] = EI * Bl[3] + P.tip_mass * w2 * Bl[0]
    return np.linalg.det(A)


def _analytic_hz(count, **kw):
    grid = np.linspace(0.5, 30.0, 3000)
    vals = [_determinant(b, **kw) for b in grid]
    roots = [brentq(lambda b: _determinant(b, **kw), a, c, xtol=1e-14)
             for a, c, va, vc in zip(grid, grid[1:], vals, vals[1:]) if np.sign(va) != np.sign(vc)]
    EI = P.youngs_modulus * P.second_moment
    return np.array(roots[:count]) ** 2 * math.sqrt(EI / P.mass_per_length) / (2 * math.pi)


def _locked_hz(elements):
    _, mbs, _ = _system(elements=elements, lock=True, gravity=0.0)
    settings = exu.SimulationSettings()
    settings.solution.file.write = False
    hz, _ = mbs.ComputeODE2Eigenvalues(simulationSettings=settings, convert2Frequencies=True)
    return np.sort(np.asarray(hz))[:2]


def test_locked_arm_frequencies_against_euler_bernoulli():
    exact = _analytic_hz(2)
    f2, f4 = _locked_hz(2), _locked_hz(4)
    # cubic Hermite elements converge as h^4: the Richardson estimate of f4's error is
    # (f2 - f4) / 15; allow a factor 2 for the pre-asymptotic range
    richardson = np.abs(f2 - f4) / 15
    assert np.all(np.abs(f4 - exact) <= 2 * richardson), (f4, exact, richardson)
    order = np.log2(np.abs(f2 - exact) / np.abs(f4 - exact))
    assert np.all((order > 3.5) & (order < 4.5)), order
    # a wrong answer is rejected: the same arm without the rotor inertia is outside the bound
    no_rotor = _analytic_hz(1, rotor_inertia=0.0)
    assert abs(f4[0] - no_rotor[0]) > 2 * richardson[0]


def test_prescribed_drives_follow_motion_and_rigid_kinematics():
    omega = 2 * math.pi
    _, mbs, drives = _system(elements=2, prescribe=True)
    tip_node = max(n for n, name, *_ in _nodes(mbs) if name.startswith("link2"))
    elbow_node = [n for n, name, *_ in _nodes(mbs) if name == "elbow_housing"][0]
    rec = []

    def post(mbs_, t):
        q = mbs_.systemData.GetODE2Coordinates()
        angles = [q[mbs_.GetMarker(d["markers"][1])["coordinate"] + mbs_.GetNodeODE2Index(
            mbs_.GetMarker(d["markers"][1])["nodeNumber"])] for d in drives]
        housing = q[mbs_.GetNodeODE2Index(elbow_node) + 2]
        rec.append((t, angles[0], angles[1] - housing,
                    np.array(mbs_.GetNodeOutput(tip_node, exu.OutputVariableType.Position))[:2]))
        return True

    mbs.SetPostStepUserFunction(post)
    s = exu.SimulationSettings()
    s.timeIntegration.endTime = 0.25
    s.timeIntegration.numberOfSteps = 250
    s.timeIntegration.verboseMode = 0
    s.solution.file.write = False
    s.linearSolver.solverType = exu.LinearSolverType.EigenDense
    assert mbs.SolveDynamic(s)
    worst_angle, worst_tip = 0.0, 0.0
    for t, a1, a2, tip in rec:
        q1, q2 = drives[0]["motion"](t)[0], drives[1]["motion"](t)[0]
        worst_angle = max(worst_angle, abs(a1 - q1), abs(a2 - q2))
        rigid = P.length1 * np.array([math.cos(q1), math.sin(q1)]) + P.length2 * np.array(
            [math.cos(q1 + q2), math.sin(q1 + q2)])
        worst_tip = max(worst_tip, float(np.linalg.norm(tip - rigid)))
        wrong = P.length1 * np.array([math.cos(q1), math.sin(q1)]) + P.length2 * np.array(
            [math.cos(q2), math.sin(q2)])  # elbow angle read as absolute
        if t > 0.05:
            assert np.linalg.norm(tip - wrong) > 0.1
    # constraints hold to the Newton tolerance
    assert worst_angle < 1e-8
    # elastic deflection bound: static cantilever deflection under the peak inertial + gravity
    # load, delta <= F L^3 / (3 EI) with F = (m_tip + motor + links) (g + L Omega^2 pi/4 (1 + pi/2))
    EI = P.youngs_modulus * P.second_moment
    F = (P.tip_mass + P.motor_mass + M1 + M2) * (P.gravity + L * omega**2 * math.pi / 4 * (1 + math.pi / 2))
    assert worst_tip < F * L**3 / (3 * EI)
    assert rec[-1][0] == pytest.approx(0.25)


def test_initial_state_is_the_rigid_motion_at_t0():
    _, mbs, drives = _system(elements=2)
    q0 = np.array(mbs.systemData.GetODE2Coordinates(configuration=exu.ConfigurationType.Initial))
    q_rigid, u1, u2 = _rigid_pose(mbs, math.pi / 2, 0.0)
    np.testing.assert_allclose(q0, q_rigid, atol=1e-15)
    v0 = np.array(mbs.systemData.GetODE2Coordinates_t(configuration=exu.ConfigurationType.Initial))
    w = math.pi / 4 * 2 * math.pi
    np.testing.assert_allclose(v0, w * u1 + w * u2, atol=1e-12)
    assert [d["name"] for d in drives] == ["shoulder", "elbow"]


@pytest.mark.parametrize("bad", [{"elements": 0}, {"tip_mass": -0.1}, {"youngs_modulus": float("nan")}])
def test_bad_options_one_clear_line(bad):
    sc = exu.SystemContainer()
    with pytest.raises(ValueError, match=next(iter(bad)).split("_")[0]):
        build(sc.AddSystem(), 2 * math.pi, **bad)
