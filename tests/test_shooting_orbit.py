"""Shooting orbit in Exudyn (validation.shooting_orbit).

Oracle: a base-excited spring-damper oscillator, written as a model file: node A
is the driven coordinate (x_A = a sin(Omega t)), mass B hangs on it by a spring k
and damper c.  The periodic steady state is the closed-form harmonic response
x_B = Re[(k + i c Omega) / (k - m Omega^2 + i c Omega) a e^{i Omega t}], and the
drive's feed-forward is the force that moves A: m_A x_A'' + k (x_A - x_B) + c (x_A' - x_B').
"""
from __future__ import annotations

import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest

exu = pytest.importorskip("exudyn")
from exudyn.itemInterface import (  # noqa: E402
    CoordinateSpringDamper,
    MarkerNodeCoordinate,
    Node1D,
    NodePointGround,
    ObjectMass1D,
)

from validation.shooting_orbit import shooting_orbit  # noqa: E402

MA, MB, K, C, A = 0.3, 1.0, 50.0, 0.4, 0.02
OMEGA = 2 * math.pi


def motion(t):
    s, c = math.sin(OMEGA * t), math.cos(OMEGA * t)
    return A * s, A * OMEGA * c, -A * OMEGA**2 * s


def build(mbs, omega):
    g = mbs.AddNode(NodePointGround())
    mg = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=g, coordinate=0))
    na = mbs.AddNode(Node1D(initialVelocities=[A * OMEGA]))
    nb = mbs.AddNode(Node1D())  # initial guess: at rest, far from the steady state
    mbs.AddObject(ObjectMass1D(mass=MA, nodeNumber=na))
    mbs.AddObject(ObjectMass1D(mass=MB, nodeNumber=nb))
    ma = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=na, coordinate=0))
    mb = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nb, coordinate=0))
    mbs.AddObject(CoordinateSpringDamper(markerNumbers=[ma, mb], stiffness=K, damping=C))
    return [{"name": "base", "markers": (mg, ma), "motion": motion}]


def steady_state(t):
    H = (K + 1j * C * OMEGA) / (K - MB * OMEGA**2 + 1j * C * OMEGA)
    z = H * A * np.exp(1j * (OMEGA * t - math.pi / 2))  # a sin = Re[a e^{i(wt - pi/2)}]
    return z.real, (1j * OMEGA * z).real, (-(OMEGA**2) * z).real


def test_shooting_orbit_against_harmonic_response():
    o = shooting_orbit(build, OMEGA)
    xb, vb, _ = steady_state(0.0)
    amp = abs(A * (K + 1j * C * OMEGA) / (K - MB * OMEGA**2 + 1j * C * OMEGA))
    # generalised alpha (2nd order): phase error ~ (Omega h)^2 / 12 = 3.3e-6 of the amplitude per
    # period, plus its numerical damping at rho_inf = 0.9: allow 1e-4 of the amplitude
    assert abs(o.q0[1] - xb) < 1e-4 * amp
    assert abs(o.v0[1] - vb) < 1e-4 * amp * OMEGA
    assert o.defect <= 1e-7
    for t in (0.1, 0.37, 0.8):
        xa, va, aa = motion(t)
        xb, vb, _ = steady_state(t)
        tau = MA * aa + K * (xa - xb) + C * (va - vb)
        # linear interpolation between steps of 1e-3 s: |tau''| h^2 / 8 ~ 1e-5 of the force scale
        assert o.torque(t)[0] == pytest.approx(tau, abs=1e-3 * K * A)
        # rejects the wrong sign convention of the reaction
        assert abs(o.torque(t)[0] + tau) > 0.1 * abs(tau)
