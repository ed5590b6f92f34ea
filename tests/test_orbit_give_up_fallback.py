"""A Newton that converges from the simulated guess must not be abandoned for a continuation that fails.

``tests/models/swinging_rod.py`` with a small support amplitude (1 mm) and an Euler-parameter node: the damped Newton from the simulated period converges in ~25 iterations (with
``continuation=False``), but its residual does not halve within the first five, so the default run
gives it up for the continuation in omega, which finds no start and the run ends "did not converge".
The orbit exists: the plain Newton's orbit is the hanging rod's small forced swing (its centre of mass
stays within 0.1 L of the hanging reference, Exudyn's one-period integration from it within the package's
shooting tolerance).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("exudyn")

from linearize.periodic_orbit import OrbitConvergenceError, find_orbit  # noqa: E402

ROD = str(Path(__file__).with_name("models") / "swinging_rod.py")


def test_small_swing_orbit_is_found_by_default():
    plain = find_orbit(ROD, 5.0, node="EP", direction="x", amplitude=1e-3, continuation=False)
    assert plain.residual <= plain.tolerance and plain.shooting_residual < 1e-2
    assert np.max(np.abs(plain.q[:, 2])) < 0.05  # hanging (L = 0.5)
    orbit = find_orbit(ROD, 5.0, node="EP", direction="x", amplitude=1e-3)  # the default must find it too
    assert orbit.residual <= orbit.tolerance and orbit.shooting_residual < 1e-2
    assert np.max(np.abs(orbit.q[:, 2])) < 0.05
    # the same orbit: the forced swing's samples agree to the collocation tolerance (relative to L)
    assert np.max(np.abs(orbit.q - plain.q)) < 1e-4


def test_rotation_vector_rod_returns_the_hanging_orbit_or_fails_clearly():
    """With a rotation-vector node Newton from this guess reaches only the inverted rod: the run must not
    return it."""
    try:
        orbit = find_orbit(ROD, 5.0, node="RV", direction="x", amplitude=1e-3)
    except OrbitConvergenceError as exc:
        assert "no orbit near the model's initial state" in str(exc)
        assert "\n" not in str(exc)
    else:
        assert np.max(np.abs(orbit.q[:, 2])) < 0.05
