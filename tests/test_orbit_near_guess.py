"""The orbit found is the one the model file sets up, not another one turns away from it.

``tests/models/swinging_rod.py`` (``NodeRigidBodyRxyz``): a damped rod hanging from a support that
oscillates along x by 1 cm or 1 mm.  The file's initial state (the guess, per the model-file contract)
hangs; the forced swing of the hanging rod is small (linear response: the swing angle is of the order
of the support amplitude over the rod's length, well below 1 rad).  The inverted rod (its centre of mass
L above the pivot) is an orbit too, but a different motion: a run that returns it answers another question
(and calls a stable hanging rod unstable).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("exudyn")

from linearize.periodic_orbit import find_orbit  # noqa: E402

ROD = str(Path(__file__).with_name("models") / "swinging_rod.py")
L = 0.5


@pytest.mark.parametrize("amplitude", [1e-2, 1e-3])
def test_the_hanging_rod_orbit_is_found_not_the_inverted_one(amplitude):
    orbit = find_orbit(ROD, 5.0, node="Rxyz", direction="x", amplitude=amplitude)
    # the centre of mass stays near its hanging reference (displacement << L) and the rod turns < 1 rad
    assert np.max(np.abs(orbit.q[:, 2])) < 0.1 * L, np.max(np.abs(orbit.q[:, 2]))
    assert np.max(np.abs(orbit.q[:, 3:6])) < 1.0, np.max(np.abs(orbit.q[:, 3:6]))


def test_the_distance_from_the_guess_counts_half_turns_not_whole_turns():
    """The measure itself: the guess's samples turned by a whole turn are the same configurations (near),
    turned by a half turn (the inverted rod) or moved by a rod's length they are not."""
    from linearize.periodic_orbit import _Collocation, _far_from_guess, _guess
    from mbs_models.model_file import build_model, resolve_model

    definition = resolve_model(ROD, node="Rxyz", direction="x", amplitude=1e-2)
    col = _Collocation(build_model(definition, 5.0), 32, "dense")
    X = _guess(col, definition)
    assert _far_from_guess(col, X) == ""
    turned = X.copy()
    turned[:, 4] += 2 * np.pi
    assert _far_from_guess(col, turned) == ""
    turned[:, 4] += np.pi
    assert "rod[4]" in _far_from_guess(col, turned)
    moved = X.copy()
    moved[:, 2] += 2 * L
    assert "rod[2]" in _far_from_guess(col, moved)


def test_the_hanging_rod_multipliers_are_the_damped_pendulum_s():
    """Independent of the solver: for the small forced swing the slowest multipliers are the linear damped
    pendulum's about the pivot, I_p = J_T + m L^2, damping torque c L^2 theta', |rho| = exp(-c L^2 T / (2 I_p))
    = 0.97133 (the inverted rod has a multiplier > 1)."""
    from linearize.constrained import linearize_orbit
    from stability.floquet import floquet

    orbit = find_orbit(ROD, 5.0, node="Rxyz", direction="x", amplitude=1e-3)
    rho = np.sort(np.abs(floquet(linearize_orbit(orbit), method="magnus6").multipliers))
    i_p = 0.02 + 1.0 * L**2
    expected = np.exp(-0.05 * L**2 * (2 * np.pi / 5.0) / (2 * i_p))
    # the swing of 1e-3 rad changes the linearisation by O(1e-6); the pair sits at the top of the spectrum
    assert abs(rho[-1] - expected) < 1e-4 and abs(rho[-2] - expected) < 1e-4, (rho[-2:], expected)
