"""The co-rotating basis of free planar points whose best-fit rotation about the origin the samples
cannot resolve: an unbalanced rotor whose whirl passes close to its bearing axis at the origin
(tests/models/unbalanced_rotor.py) against the closed form of the anisotropic Laval rotor
(tests/_laval_oracle.py; the model is linear, so its multipliers do not depend on the orbit)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("exudyn")

import _laval_oracle as oracle  # noqa: E402  (tests/ helper)

MODEL = str(Path(__file__).with_name("models") / "unbalanced_rotor.py")
#: as tests/test_laval_rotor.py: the adaptive engine's rtol 1e-9 plus Exudyn's numerical Jacobian of the
#: shaft's user function (measured <= 3.5e-9)
TOLERANCE = 1e-8


def _distance(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(max(np.min(np.abs(b - x)) for x in a))


@pytest.mark.parametrize("W", [30.0, 31.0])
def test_whirl_passing_near_the_origin_matches_the_closed_form(W):
    from linearize import analyze

    res = analyze(MODEL, W, n_steps=None)
    q = res.orbit.q
    closest = float(np.min(np.hypot(q[:, 0], q[:, 1])))
    assert closest < 1e-4 < float(np.max(np.hypot(q[:, 0], q[:, 1])))  # the whirl passes close to the axis
    assert _distance(res.floquet.multipliers, oracle.multipliers(W)) < TOLERANCE
    assert _distance(res.floquet.multipliers, oracle.multipliers(W * (1 + 1e-6))) > 100 * TOLERANCE


def test_frame_of_a_resolved_whirl_still_co_rotates():
    """Far from the origin (a large unbalance: a whirl of radius ~1 cm about it) the fit is the whirl's
    own smooth angle and is kept: the frame turns once per period."""
    from linearize import find_orbit
    from linearize.constrained import corotating_frame

    orbit = find_orbit(MODEL, 30.0, eccentricity=1.0)
    F = corotating_frame(orbit)
    angle = np.unwrap(np.arctan2(F[:, 1, 0], F[:, 0, 0]))
    assert abs(angle[-1] - angle[0]) > 0.9 * 2 * np.pi * (len(angle) - 1) / len(angle)
