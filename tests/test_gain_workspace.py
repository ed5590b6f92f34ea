"""The gain-parametrised Floquet workspace against systems built with the gains inside.

Oracle: the same second-order system written with ``K + kp e e^T`` and
``C + kd e e^T`` directly (an independent construction of ``P``), evaluated by
:func:`stability.floquet` with the same scheme and step count.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from stability import SecondOrderPeriodicSystem, floquet
from stability.gains import FloquetWorkspace, pd_gain_family

T = 1.0
_rng = np.random.default_rng(4)
F = 3
_M1 = _rng.standard_normal((F, F)) * 0.1
_K0 = np.diag([0.5, 40.0, 300.0])
_K1 = _rng.standard_normal((F, F))
_K1 = 5.0 * (_K1 + _K1.T)


def _system(kp: float, kd: float) -> SecondOrderPeriodicSystem:
    def M(t):
        t = np.atleast_1d(t)
        return np.eye(F)[None] + np.sin(2 * math.pi * t)[:, None, None] * (_M1 @ _M1.T)[None]

    def C(t):
        t = np.atleast_1d(t)
        c = np.broadcast_to(0.01 * np.eye(F), (t.size, F, F)).copy()
        c[:, 0, 0] += kd
        return c

    def K(t):
        t = np.atleast_1d(t)
        k = _K0[None] + np.cos(2 * math.pi * t)[:, None, None] * _K1[None]
        k[:, 0, 0] += kp
        return k

    return SecondOrderPeriodicSystem(T, M, C, K, vectorized=True)


@pytest.mark.parametrize("method, n_steps", [("magnus2", 256), ("magnus6", 64)])
def test_workspace_equals_the_system_built_with_the_gains(method, n_steps):
    ws = FloquetWorkspace(pd_gain_family(_system(0.0, 0.0), index=0), n_steps, method=method)
    for kp, kd in [(0.0, 0.0), (3.0, 0.5), (20.0, 4.0)]:
        got = ws.floquet((kp, kd))
        ref = floquet(_system(kp, kd), method=method, n_steps=n_steps, error_estimate=False)
        # same scheme, same nodes; only the (exact) balancing similarity and rounding differ
        np.testing.assert_allclose(got.moduli, ref.moduli, rtol=1e-10, atol=1e-12 * ref.moduli[0])
        np.testing.assert_allclose(got.monodromy, ref.monodromy, rtol=1e-9, atol=1e-10 * np.abs(ref.monodromy).max())


def test_workspace_rejects_wrong_gains_and_detects_a_wrong_family():
    fam = pd_gain_family(_system(0.0, 0.0), index=0)
    ws = FloquetWorkspace(fam, 64, method="magnus6")
    with pytest.raises(ValueError, match="gains"):
        ws.floquet((1.0,))
    # the comparison above would catch a family with the gain on the wrong coordinate
    wrong = FloquetWorkspace(pd_gain_family(_system(0.0, 0.0), index=1), 64, method="magnus6")
    ref = floquet(_system(20.0, 4.0), method="magnus6", n_steps=64, error_estimate=False)
    assert not np.allclose(wrong.floquet((20.0, 4.0)).moduli, ref.moduli, rtol=1e-6)
