"""Rotation-vector (Lie group) nodes, ``NodeRigidBodyRotVecLG``.

Exudyn's conventions for such a node, checked here against Exudyn itself: its three rotation velocity
coordinates are the body-fixed angular velocity (not the derivative of the rotation vector), its constraint
Jacobian is taken with respect to body-fixed rotation increments (``C_q T(nu) = dC/dnu`` with the tangent
operator ``T``), and its integrator re-charts the vector when its length passes 2 pi.  The adapter
(:mod:`linearize.exudyn_system`) presents the node in the rotation-vector chart (velocity ``nu'``), and a
node that turns in a Tait-Bryan chart about the turn's axis.
References: the same rod with a ``NodeRigidBodyEP`` and with a ``NodeRigidBodyRxyz`` node (independent
parametrisations); the rotor on a turning hub (tests/models/hub_rotor.py) with a ``NodeRigidBodyEP`` node;
hand-written rotation matrices for the chart's conversions.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("exudyn")

from linearize import analyze  # noqa: E402
from mbs_models.model_file import build_model, resolve_model  # noqa: E402

MODELS = Path(__file__).with_name("models")
from test_rotating_orbits import _distance  # noqa: E402  (multipliers matched, not sorted: pairs of equal ones)

ROD = str(MODELS / "swinging_rod.py")
W = 5.0
#: Agreement of independent parametrisations at an orbit at rest: the adaptive Floquet solve and the
#: numerical force Jacobians (measured 1e-10 apart on the held-out Euler-parameter models).
TOLERANCE = 1e-8


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _tangent_operator(v):
    """``T(nu)`` with body-fixed angular velocity ``omega = T(nu) nu'`` (hand-derived from
    ``R(nu) = exp(skew(nu))``)."""
    th = float(np.linalg.norm(v))
    s = _skew(v)
    return np.eye(3) - (1 - math.cos(th)) / th ** 2 * s + (th - math.sin(th)) / th ** 3 * s @ s


def _rotation(v):
    th = float(np.linalg.norm(v))
    s = _skew(v)
    if th == 0.0:
        return np.eye(3)
    return np.eye(3) + math.sin(th) / th * s + (1 - math.cos(th)) / th ** 2 * s @ s


def test_exudyn_constraint_jacobian_is_taken_in_body_fixed_rotations():
    """Exudyn's ``C_q T(nu)`` and the adapter's ``C_q`` equal central differences of ``C`` in the rotation
    vector; Exudyn's ``C_q`` alone does not."""
    from linearize.exudyn_system import ExudynSystem

    system = ExudynSystem(build_model(resolve_model(ROD, node="RV"), W))
    q = np.zeros(system.n)
    q[3:6] = [0.5, 0.3, 0.2]
    t, h = 0.1, 1e-6
    fd = np.array([(system.constraints(q + h * e, t) - system.constraints(q - h * e, t)) / (2 * h)
                   for e in np.eye(system.n)]).T
    raw = system._ae_jacobian_full(q, t)[system.active]
    assert np.max(np.abs(raw[:, 3:6] @ _tangent_operator(q[3:6]) - fd[:, 3:6])) < 1e-8
    assert np.max(np.abs(system.constraint_jacobian(q, t) - fd)) < 1e-8
    assert np.max(np.abs(raw[:, 3:6] - fd[:, 3:6])) > 1e-2  # the check can fail


def test_tangent_operator_gives_the_body_fixed_angular_velocity():
    """``T(nu) nu'`` against ``R^T R'`` of the hand-written rotation matrix by central differences, also
    below the series threshold; the adapter's velocity conversions invert each other."""
    from linearize.exudyn_system import from_exudyn_velocity, tangent_operator, to_exudyn_velocity

    rate = np.array([0.3, -0.7, 0.4])
    for nu in (np.array([0.5, 0.3, 0.2]), np.array([2.0, -1.5, 2.5]), np.array([1e-6, 2e-6, -1e-6])):
        h = 1e-6
        dR = (_rotation(nu + h * rate) - _rotation(nu - h * rate)) / (2 * h)
        W_ = _rotation(nu).T @ dR
        omega = np.array([W_[2, 1], W_[0, 2], W_[1, 0]])
        assert np.max(np.abs(tangent_operator(nu) @ rate - omega)) < 1e-8
        assert np.max(np.abs(tangent_operator(nu).T @ rate - omega)) > 1e-7 or np.linalg.norm(nu) < 1e-3
    nodes = [(np.array([3, 4, 5]), np.array([0.1, 0.0, 0.0]))]
    q, v = np.array([0, 0, 0, 0.4, 0.2, -0.3]), np.array([1.0, 2.0, 3.0, 0.3, -0.7, 0.4])
    w = to_exudyn_velocity(nodes, q, v)
    assert np.allclose(w[:3], v[:3]) and not np.allclose(w[3:], v[3:])
    assert np.max(np.abs(from_exudyn_velocity(nodes, q, w) - v)) < 1e-14


def test_exudyn_spins_a_rotation_vector_node_with_angular_velocity_and_recharts_it():
    """A free body spinning about a principal axis for 1.5 turns: the velocity coordinates stay the constant
    body-fixed angular velocity, the vector never exceeds the length 2 pi (it is re-charted), and the rotation
    it represents is the exact ``exp(t skew(omega))`` throughout."""
    import exudyn as exu
    from exudyn.itemInterface import NodeRigidBodyRotVecLG, ObjectRigidBody

    w = 6.0 * np.array([1.0, 0.0, 0.0])
    mbs = exu.SystemContainer().AddSystem()
    node = mbs.AddNode(NodeRigidBodyRotVecLG(referenceCoordinates=[0] * 6, initialVelocities=[0, 0, 0, *w]))
    mbs.AddObject(ObjectRigidBody(nodeNumber=node, mass=1.0, inertia=[0.05, 0.05, 0.05, 0, 0, 0]))
    mbs.Assemble()
    period = 2 * math.pi / float(np.linalg.norm(w))
    s = exu.SimulationSettings()
    s.timeIntegration.endTime, s.timeIntegration.numberOfSteps = 1.5 * period, 300
    s.timeIntegration.verboseMode, s.solution.file.write = 0, False
    rows = []
    mbs.SetPostStepUserFunction(lambda m, t: rows.append((t, np.array(m.systemData.GetODE2Coordinates()),
                                                          np.array(m.systemData.GetODE2Coordinates_t()))) or True)
    mbs.SolveDynamic(s, solverType=exu.DynamicSolverType.RK44)
    vectors = np.array([q[3:6] for _, q, _ in rows])
    assert max(np.max(np.abs(v[3:6] - w)) for _, _, v in rows) < 1e-12
    assert np.max(np.linalg.norm(vectors, axis=1)) <= 2 * math.pi + 1e-9
    assert np.max(np.linalg.norm(np.diff(vectors, axis=0), axis=1)) > math.pi  # re-charted at least once
    err = max(np.max(np.abs(_rotation(q[3:6]) - _rotation(t * w))) for t, q, _ in rows)
    assert err < 1e-9
    # the vector itself is not t w after the turn (a check that it moved charts can fail)
    assert np.max(np.abs(vectors[-1] - rows[-1][0] * w)) > 1.0


def test_rotation_vector_node_at_rest_gives_the_euler_parameter_multipliers():
    """The rod hanging under a vertically oscillating support (its orbit does not rotate it): the
    rotation-vector node is accepted and its multipliers are the Euler-parameter ones."""
    ep = analyze(ROD, W, n_steps=None, node="EP", direction="z", amplitude=0.02).floquet.multipliers
    rv = analyze(ROD, W, n_steps=None, node="RV", direction="z", amplitude=0.02).floquet.multipliers
    assert _distance(ep, rv) <= TOLERANCE
    assert np.max(np.abs(np.abs(ep) - 1.0)) > 1e-3  # damped: not trivially on the unit circle


def test_swinging_rotation_vector_node_gives_the_tait_bryan_multipliers():
    """The rod swinging about a fixed axis (rotation vector up to 0.55 rad): the rotation-vector node's
    multipliers are the Tait-Bryan ones."""
    rv = analyze(ROD, W, n_steps=None, node="RV")
    rx = analyze(ROD, W, n_steps=None, node="Rxyz")
    assert float(np.max(np.abs(rv.orbit.q[:, 3:6]))) > 0.5
    assert _distance(rv.floquet.multipliers, rx.floquet.multipliers) \
        <= TOLERANCE


@pytest.mark.slow
def test_rotation_vector_chart_agrees_with_euler_parameters_and_is_needed(monkeypatch):
    """EP, Rxyz and RV agree on the swinging rod; without the adapter's chart (Exudyn's angular velocities
    taken as the vector's rates, a wrong answer) two multipliers are off by far more than that."""
    import linearize.exudyn_system as exudyn_system

    ep = np.sort_complex(analyze(ROD, W, n_steps=None, node="EP").floquet.multipliers)
    rx = np.sort_complex(analyze(ROD, W, n_steps=None, node="Rxyz").floquet.multipliers)
    rv = np.sort_complex(analyze(ROD, W, n_steps=None, node="RV").floquet.multipliers)
    assert _distance(ep, rx) <= TOLERANCE and _distance(ep, rv) <= TOLERANCE
    monkeypatch.setattr(exudyn_system, "lie_group_nodes", lambda mbs: [])
    wrong = np.sort_complex(analyze(ROD, W, n_steps=None, node="RV").floquet.multipliers)
    assert _distance(ep, wrong) > 1e-2


def _rv_rod_file(tmp_path):
    model = tmp_path / "swinging_rod_rv.py"
    model.write_text(f"import importlib.util\n"
                     f"spec = importlib.util.spec_from_file_location('rod', {ROD!r})\n"
                     f"rod = importlib.util.module_from_spec(spec)\n"
                     f"spec.loader.exec_module(rod)\n\n\n"
                     f"def build(mbs, omega):\n"
                     f"    return rod.build(mbs, omega, node='RV')\n")
    return str(model)


def test_cli_floquet_on_a_rotation_vector_node(tmp_path, capsys):
    import json

    from flexstab.cli import main

    code = main(["floquet", "--model", _rv_rod_file(tmp_path), "--omega", str(W), "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code in (0, 1)  # a verdict, not a refusal
    assert d["turns"] == {} and d["sign_flips"] == []
    assert len(d["multipliers"]) == 4


def test_cli_validate_refuses_a_rotation_vector_node_with_exit_2(tmp_path, capsys):
    from flexstab.cli import main

    code = main(["validate", "--model", _rv_rod_file(tmp_path), "--omega", str(W)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "validate does not run models with a NodeRigidBodyRotVecLG" in err


def _tait_bryan(theta):
    """``Rx Ry Rz``, written out from the three elementary rotations."""
    c, s = np.cos(theta), np.sin(theta)
    rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    return rx @ ry @ rz


def test_tait_bryan_chart_of_a_turning_node_against_hand_written_rotations():
    """The chart ``R = C1 Rx Ry Rz C2`` of a node turning about a generic axis: advancing the first angle
    turns ``R`` about that axis, ``rate_map(theta) theta'`` is the body-fixed angular velocity ``R^T R'`` (central
    differences), Exudyn's coordinates are a rotation vector of ``R`` (less the reference), and the angles come
    back from them whole turns included."""
    from linearize.exudyn_system import tait_bryan_rate_matrix, turning_chart

    axis = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
    ref = np.array([0.2, 0.1, -0.4])
    chart = turning_chart(np.array([3, 4, 5]), ref, axis, _rotation(np.array([0.7, -0.2, 1.1])))
    theta, rate, h = np.array([7.3, 0.25, -0.6]), np.array([30.0, 0.4, -0.9]), 1e-6
    assert np.max(np.abs(chart.rotation(np.zeros(3)) - _rotation(np.array([0.7, -0.2, 1.1])))) < 1e-14
    turned = chart.rotation(theta + np.array([0.9, 0.0, 0.0]))
    assert np.max(np.abs(turned - _rotation(0.9 * axis) @ chart.rotation(theta))) < 1e-14
    dR = (chart.rotation(theta + h * rate) - chart.rotation(theta - h * rate)) / (2 * h)
    W_ = chart.rotation(theta).T @ dR
    omega = np.array([W_[2, 1], W_[0, 2], W_[1, 0]])
    assert np.max(np.abs(chart.rate_map(theta) @ rate - omega)) < 1e-6 * np.linalg.norm(rate)
    dT = (_tait_bryan(theta + h * rate) - _tait_bryan(theta - h * rate)) / (2 * h)
    W_ = _tait_bryan(theta).T @ dT
    assert np.max(np.abs(tait_bryan_rate_matrix(theta) @ rate - np.array([W_[2, 1], W_[0, 2], W_[1, 0]]))) < 1e-6 * 30
    nu = chart.exudyn_coordinates(theta)
    assert np.linalg.norm(nu + ref) <= math.pi + 1e-12
    assert np.max(np.abs(_rotation(nu + ref) - chart.rotation(theta))) < 1e-13
    assert np.max(np.abs(chart.angles(nu, theta + 0.3) - theta)) < 1e-12  # theta_1 = 7.3: beyond a turn
    assert np.max(np.abs(chart.angles(nu, theta - [2 * math.pi, 0, 0]) - theta + [2 * math.pi, 0, 0])) < 1e-12


def _hub_rotor(**options):
    return analyze(str(MODELS / "hub_rotor.py"), 30.0, n_steps=None, hub="constraint", rtol=1e-10, **options)


def test_turning_rotation_vector_rotor_gives_the_euler_parameter_multipliers_and_needs_its_chart(monkeypatch):
    """The rotor carried by the turning hub with a rotation-vector node (one turn per period): presented in
    its Tait-Bryan chart (one turn of the first angle), its multipliers are those of the same rotor with
    Euler parameters (sign flip map; both against the Newton-Euler oracle: tests/test_turning_euler_parameters.py),
    within the tolerance of independent parametrisations.  With the chart's velocity map taken as constant
    (Exudyn's angular velocities as the angles' rates, a wrong answer) they are not."""
    import linearize.exudyn_system as exudyn_system

    ep = _hub_rotor(node="EP")
    rv = _hub_rotor(node="RV")
    assert rv.orbit.summary()["turns"] == {"hub[3]": 1, "rotor[9]": 1} and rv.orbit.summary()["sign_flips"] == []
    assert len(rv.orbit.charts) == 1 and rv.orbit.shooting_residual < 1e-5
    assert len(rv.floquet.multipliers) == 12
    assert _distance(ep.floquet.multipliers, rv.floquet.multipliers) \
        <= TOLERANCE
    monkeypatch.setattr(exudyn_system.TurningChart, "rate_map", lambda self, theta: self.inner.T + 0 * theta[0])
    wrong = _hub_rotor(node="RV")
    assert _distance(ep.floquet.multipliers, wrong.floquet.multipliers) \
        > 100 * TOLERANCE


def test_cli_floquet_on_a_turning_rotation_vector_node(tmp_path, capsys):
    """``flexstab floquet --model`` on the hub rotor with a rotation-vector node: a verdict (no refusal), the
    rotor's chart angle reported as a whole turn, the multipliers of the Euler-parameter rotor to the
    accuracy contract (``--rtol``, default 1e-6)."""
    import json

    from flexstab.cli import main

    model = tmp_path / "hub_rotor_rv.py"
    model.write_text(f"import importlib.util\n"
                     f"spec = importlib.util.spec_from_file_location('hub', {str(MODELS / 'hub_rotor.py')!r})\n"
                     f"hub = importlib.util.module_from_spec(spec)\n"
                     f"spec.loader.exec_module(hub)\n\n\n"
                     f"def build(mbs, omega):\n"
                     f"    return hub.build(mbs, omega, node='RV')\n")
    code = main(["floquet", "--model", str(model), "--omega", "30", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code in (0, 1)  # a verdict, not a refusal (exit 2)
    assert d["turns"] == {"hub[3]": 1, "rotor[9]": 1} and d["sign_flips"] == []
    mu = np.array([complex(re, im) for re, im in d["multipliers"]])
    ep = _hub_rotor(node="EP").floquet.multipliers
    assert len(mu) == 12
    assert _distance(mu, ep) <= 1e-6


def test_rotation_vector_rotor_turning_twice_per_period_gives_the_euler_parameter_multipliers():
    """Two whole turns per period (the hub at 2 omega; Euler parameters then come back with their own
    sign, the rotation vector passes its singular length mid-period): the rotation-vector rotor's
    multipliers are the Euler-parameter rotor's, within the tolerance of independent parametrisations,
    and both report the two turns."""
    ep = analyze(str(MODELS / "hub_rotor.py"), 15.0, n_steps=None, rtol=1e-10, node="EP", turns=2)
    rv = analyze(str(MODELS / "hub_rotor.py"), 15.0, n_steps=None, rtol=1e-10, node="RV", turns=2)
    assert ep.orbit.summary()["turns"] == {"hub[3]": 2} and ep.orbit.summary()["sign_flips"] == []
    assert rv.orbit.summary()["turns"] == {"hub[3]": 2, "rotor[9]": 2}
    assert _distance(ep.floquet.multipliers, rv.floquet.multipliers) <= TOLERANCE
    # not the one-turn rotor at the same period (a different machine: the check can fail)
    one = analyze(str(MODELS / "hub_rotor.py"), 15.0, n_steps=None, rtol=1e-10, node="EP")
    assert _distance(one.floquet.multipliers, rv.floquet.multipliers) > 100 * TOLERANCE


@pytest.mark.parametrize("angle", [1e-6, 1.01e-4, 1e-2, 0.3, 0.49, 0.51, 1.0, 2.5])
def test_tangent_operator_and_rotation_are_accurate_to_rounding_at_every_angle(angle):
    """T(nu) and exp(skew nu) against their series summed in 60-digit decimal arithmetic (independent of
    the float code): within a few units of rounding at every angle, also just above the series threshold
    (where the closed forms (1 - cos a) / a^2 and (a - sin a) / a^3 lose digits to cancellation)."""
    from decimal import Decimal, getcontext

    from linearize.exudyn_system import rotation_matrix, tangent_operator

    getcontext().prec = 60
    axis = np.array([0.3, -0.5, 0.81])
    nu = angle * axis / np.linalg.norm(axis)
    a2 = sum(Decimal(float(x)) ** 2 for x in nu)
    coef = []
    for j in (1, 2, 3):
        total, term, k, fact = Decimal(0), Decimal(1), 0, Decimal(math.factorial(j))
        while True:
            piece = term / fact
            total += piece
            if abs(piece) < Decimal(10) ** -40:
                break
            k += 1
            term = -term * a2
            fact = Decimal(math.factorial(2 * k + j))
        coef.append(float(total))
    S = np.array([[0, -nu[2], nu[1]], [nu[2], 0, -nu[0]], [-nu[1], nu[0], 0]])
    T_ref = np.eye(3) - coef[1] * S + coef[2] * (S @ S)
    R_ref = np.eye(3) + coef[0] * S + coef[1] * (S @ S)
    assert np.max(np.abs(tangent_operator(nu) - T_ref)) <= 4e-16
    assert np.max(np.abs(rotation_matrix(nu) - R_ref)) <= 4e-16
