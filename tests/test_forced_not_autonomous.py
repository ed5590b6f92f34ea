"""A model without drives whose load depends on time is not autonomous, whatever times the check samples.

Oracle: ``tests/models/pulse_forced_mass.py``, a point mass on an inverted spring (x) with a dashpot, hit once
per period by a smooth load pulse (compact support, 0.3 T long around t = 0 mod T).  The equations are linear
with constant coefficients, so the multipliers are ``exp(lambda T)`` with ``lambda^2 + c lambda - a = 0`` (x)
and ``lambda^2 + lambda + 40 = 0`` (y, z), whatever the load; the periodic forced response exists (no
multiplier is 1).  A time shift of it is no orbit: no multiplier may be left out as structural.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("exudyn")

from linearize.analysis import analyze  # noqa: E402

MODEL = str(Path(__file__).with_name("models") / "pulse_forced_mass.py")


@pytest.mark.parametrize("pulse", [True, False])
def test_a_periodically_hit_mass_is_forced_not_autonomous(pulse):
    # pulse=False: F cos(omega t + 0.15 pi), equal at 0.21 T and 0.64 T
    res = analyze(MODEL, 2 * math.pi, n_steps=None, rtol=1e-8, pulse=pulse, samples=64)
    assert not res.orbit.autonomous and res.structural == ()
    a, c = 0.1, 5.0
    exact = sorted(np.abs(np.exp(np.roots([1, c, -a]))).tolist() + [math.exp(-0.5)] * 4, reverse=True)
    got = np.sort(np.abs(res.floquet.multipliers))[::-1]
    assert np.allclose(got, exact, rtol=1e-6)
    assert res.verdict.verdict == "unstable"  # 1.0201 > 1: the growing multiplier is judged
