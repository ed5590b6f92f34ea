"""Tests of :class:`mbs_models.parameters.ManipulatorParameters`.

Oracle: Table 1 of the reference paper (Dat, Khang, Hoang, Quyen, "Stability
Control of Dynamical Systems Described by Linear Differential Equations with
Time-Periodic Coefficients", proceedings p. 489), transcribed by hand below,
and the package's validation rules (non-positive length/area/density/
stiffness/inertia, negative tip mass/damping/gravity, NaN, inf, non-numbers
-> ``ValueError`` naming the field).
"""
from __future__ import annotations

import dataclasses
import math
import re

import pytest

from mbs_models.parameters import ManipulatorParameters

#: Table 1 of the paper (p. 489), field name -> printed value; g is not printed (9.81).
TABLE1 = {
    "length": 0.9,
    "area": 4e-4,
    "density": 2700.0,
    "second_moment": 1.3333e-8,
    "youngs_modulus": 7.11e10,
    "hub_inertia": 5.86e-5,
    "tip_mass": 0.1,
    "joint_damping": 0.01,
    "gravity": 9.81,
}

STRICTLY_POSITIVE = ["length", "area", "density", "second_moment", "youngs_modulus", "hub_inertia"]
NON_NEGATIVE = ["tip_mass", "joint_damping", "gravity"]
ALL_FIELDS = STRICTLY_POSITIVE + NON_NEGATIVE


def test_field_set_is_table1():
    assert {f.name for f in dataclasses.fields(ManipulatorParameters)} == set(TABLE1)


@pytest.mark.parametrize("name, value", sorted(TABLE1.items()))
def test_defaults_are_table1(name, value):
    # exact: the defaults are the printed decimal literals
    assert getattr(ManipulatorParameters(), name) == value


def test_derived_quantities_from_table1():
    p = ManipulatorParameters()
    # rho A = 2700 * 4e-4 = 1.08 kg/m, m_OE = 1.08 * 0.9 = 0.972 kg, EI = 7.11e10 * 1.3333e-8
    assert p.mass_per_length == pytest.approx(1.08, rel=1e-15)
    assert p.link_mass == pytest.approx(0.972, rel=1e-15)
    assert p.bending_stiffness == pytest.approx(947.9763, rel=1e-12)
    assert p.axial_stiffness == pytest.approx(2.844e7, rel=1e-12)


def test_frozen():
    p = ManipulatorParameters()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.length = 1.0  # type: ignore[misc]


def test_ints_are_accepted_and_normalised():
    p = ManipulatorParameters(density=2700, tip_mass=0)
    assert isinstance(p.density, float) and p.density == 2700.0
    assert p.tip_mass == 0.0


@pytest.mark.parametrize("name", NON_NEGATIVE)
def test_zero_allowed_for_non_negative_fields(name):
    assert getattr(ManipulatorParameters(**{name: 0.0}), name) == 0.0


def _raises_naming(name, value):
    with pytest.raises(ValueError, match=rf"\b{re.escape(name)}\b"):
        ManipulatorParameters(**{name: value})


@pytest.mark.parametrize("name", STRICTLY_POSITIVE)
@pytest.mark.parametrize("value", [0.0, -1.0, -1e-12])
def test_non_positive_rejected(name, value):
    _raises_naming(name, value)


@pytest.mark.parametrize("name", NON_NEGATIVE)
@pytest.mark.parametrize("value", [-1.0, -1e-12])
def test_negative_rejected(name, value):
    _raises_naming(name, value)


@pytest.mark.parametrize("name", ALL_FIELDS)
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_rejected(name, value):
    _raises_naming(name, value)


@pytest.mark.parametrize("name", ALL_FIELDS)
@pytest.mark.parametrize("value", ["0.9", None, True, [1.0]])
def test_non_number_rejected(name, value):
    _raises_naming(name, value)


def test_round_trip_through_mapping():
    p = ManipulatorParameters(length=1.2, tip_mass=0.3)
    assert ManipulatorParameters.from_mapping(p.to_dict()) == p
    # missing keys take the Table 1 defaults
    assert ManipulatorParameters.from_mapping({}) == ManipulatorParameters()


def test_from_mapping_rejects_unknown_keys():
    with pytest.raises(ValueError, match=r"unknown.*\blenght\b"):
        ManipulatorParameters.from_mapping({"lenght": 0.9})


def test_from_mapping_validates_values():
    with pytest.raises(ValueError, match=r"\bjoint_damping\b"):
        ManipulatorParameters.from_mapping({"joint_damping": -0.01})
