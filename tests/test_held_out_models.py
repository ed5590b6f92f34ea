"""Model files written as a user would (tests/models/), run through ``flexstab floquet --model FILE
--json``, each against a reference independent of the package:

* ``forced_pendulum_3d.py`` (a rod with Euler parameters hanging from a vertically oscillating support):
  the hand-derived swing equation ``J_p th'' + c L^2 th' + L (m (g + z'') + c z') th = 0`` (two equal
  copies), integrated by scipy (DOP853, rtol 1e-12);
* ``periodic_stiffness_chain.py`` (three carts, the middle spring pulsing): ``M x'' + C x' + K(t) x = 0``
  written out by hand, integrated the same way;
* ``unbalanced_rotor.py`` (a Jeffcott rotor whose whirl passes close to its bearing axis): the closed
  form of tests/_laval_oracle.py;
* ``hub_rotor.py`` (a rotor with Euler parameters turning with a hub): the hand-written Newton-Euler
  model of tests/_hub_rotor_reference.py (slow: its complex-step monodromy takes ~4 s).
"""
from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate

pytest.importorskip("exudyn")

import _laval_oracle as laval  # noqa: E402  (tests/ helpers)

MODELS = Path(__file__).with_name("models")
W = 30.0
#: the CLI is asked for rtol 1e-9 on the propagator; the linearisation reads Exudyn's numerical force
#: Jacobians (measured on these models: <= 5e-10 apart from the references), the references are
#: integrated to rtol 1e-12
TOLERANCE = 1e-8


def _module(name):
    spec = importlib.util.spec_from_file_location(name, MODELS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _cli_multipliers(name, capsys, omega=W):
    from flexstab.cli import main

    code = main(["floquet", "--model", str(MODELS / f"{name}.py"), "--omega", str(omega), "--rtol", "1e-9",
                 "--json"])
    d = json.loads(capsys.readouterr().out)
    assert code in (0, 1), code  # a verdict, not bad input
    return np.array([complex(*m) for m in d["multipliers"]]), d


def _monodromy(rhs, n, period):
    cols = [scipy.integrate.solve_ivp(rhs, (0.0, period), e, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
            for e in np.eye(n)]
    return np.array(cols).T


def _distance(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(max(max(np.min(np.abs(b - x)) for x in a), max(np.min(np.abs(a - x)) for x in b)))


def pendulum_reference(omega, amplitude=None):
    p = _module("forced_pendulum_3d")
    A = p.AMPLITUDE if amplitude is None else amplitude
    m, L, c, g = p.MASS, p.L, p.DAMPING, p.GRAVITY
    Jp = p.J_T + m * L * L

    def rhs(t, y):
        zd, zdd = A * omega * math.cos(omega * t), -A * omega ** 2 * math.sin(omega * t)
        return [y[1], -(c * L * L * y[1] + L * (m * (g + zdd) + c * zd) * y[0]) / Jp]

    mu = np.linalg.eigvals(_monodromy(rhs, 2, 2 * math.pi / omega))
    return np.concatenate([mu, mu])  # two equal swing planes


def chain_reference(omega, eps=None):
    ch = _module("periodic_stiffness_chain")
    e = ch.EPS if eps is None else eps
    M = np.diag(ch.MASSES)
    C = ch.C * np.array([[2.0, -1, 0], [-1, 2, -1], [0, -1, 1]])

    def K(t):
        k2 = ch.K2 * (1 + e * math.cos(omega * t))
        return np.array([[ch.K1 + k2, -k2, 0], [-k2, k2 + ch.K3, -ch.K3], [0, -ch.K3, ch.K3]])

    Minv = np.linalg.inv(M)

    def rhs(t, y):
        return np.concatenate([y[3:], -Minv @ (C @ y[3:] + K(t) @ y[:3])])

    return np.linalg.eigvals(_monodromy(rhs, 6, 2 * math.pi / omega))


def test_forced_3d_pendulum(capsys):
    mu, d = _cli_multipliers("forced_pendulum_3d", capsys)
    assert len(mu) == 4 and d["independent_coordinates"] == 2
    assert _distance(mu, pendulum_reference(W)) <= TOLERANCE
    assert _distance(mu, pendulum_reference(W, amplitude=0.0)) > 1e-3  # the support's motion matters


def test_periodic_stiffness_chain(capsys):
    mu, d = _cli_multipliers("periodic_stiffness_chain", capsys)
    assert len(mu) == 6 and d["independent_coordinates"] == 3  # the lateral coordinates are held
    assert _distance(mu, chain_reference(W)) <= TOLERANCE
    assert _distance(mu, chain_reference(W, eps=0.29)) > 100 * TOLERANCE


def test_unbalanced_rotor(capsys):
    mu, _ = _cli_multipliers("unbalanced_rotor", capsys)
    assert _distance(mu, laval.multipliers(W)) <= TOLERANCE
    assert _distance(mu, laval.multipliers(W * (1 + 1e-6))) > 100 * TOLERANCE


@pytest.mark.slow
def test_rotor_with_euler_parameters_on_a_turning_hub(capsys):
    import _hub_rotor_reference as hub

    mu, d = _cli_multipliers("hub_rotor", capsys)
    assert d["sign_flips"] == [f"rotor[{i}]" for i in range(9, 13)] and d["turns"] == {"hub[3]": 1}
    assert _distance(mu, hub.multipliers(W, 9.81)) <= TOLERANCE
    assert _distance(mu, hub.multipliers(W * (1 + 1e-6), 9.81)) > 100 * TOLERANCE
