"""Pieces of the two-link study (flexstab.two_link) that need no orbit."""
from __future__ import annotations

import pytest

from flexstab.two_link import dominant_damped, main_dominant


def _m(mode, undamped=False):
    return {"mode": mode, "undamped": undamped}


def test_main_dominant_prefers_drive_and_first_bending_modes():
    mus = [0.66 + 0.1j, 0.66 - 0.1j, 0.30, 0.2, 1.0]
    modes = [_m("axial 9"), _m("axial 9"), _m("elbow"), _m("bending 1"), _m("axial 2", True)]
    # the axial artefact is larger but is not one of the modes a rigid / one-mode model has
    assert main_dominant(mus, modes, ("shoulder", "elbow")) == pytest.approx(0.30)
    # without drive / bending-1 modes: the largest off the unit circle
    assert main_dominant(mus[:2] + [1.0], modes[:2] + [_m("axial 2", True)], ("shoulder",)) == pytest.approx(0.66 + 0.1j)
    # an undamped drive mode does not count
    assert main_dominant([1.0005, 0.4], [_m("elbow", True), _m("shoulder")], ("shoulder", "elbow")) == pytest.approx(0.4)


def test_dominant_damped_skips_the_unit_circle():
    assert dominant_damped([1.0009, -0.9995, 0.71, 0.2]) == pytest.approx(0.71)
    assert dominant_damped([1.0, 0.9999]) == pytest.approx(1.0)  # nothing off the circle: the largest
