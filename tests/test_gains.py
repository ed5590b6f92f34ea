"""``stability.gains.Gains``: one (kp, kd) pair per drive, and the interleaved vector a Taguchi run varies."""
from __future__ import annotations

import dataclasses

import pytest

from stability.gains import Gains


def test_interleaved_round_trip_and_pair_order():
    g = Gains.from_interleaved((1.0, 2.0, 3.0, 4.0))
    assert g.kp == (1.0, 3.0) and g.kd == (2.0, 4.0) and g.drives == 2
    # a split into halves ((1, 2), (3, 4)) would be the wrong reading of (kp1, kd1, kp2, kd2)
    assert g.kp != (1.0, 2.0)
    assert g.interleaved() == (1.0, 2.0, 3.0, 4.0)
    assert Gains.from_interleaved(g.interleaved()) == g
    assert Gains.from_arrays([1.0, 3.0], [2.0, 4.0]) == g
    assert Gains.from_arrays(5.0, 0.5) == Gains.from_interleaved([5.0, 0.5])


def test_arguments_are_floats_for_one_drive_and_one_value_per_drive_otherwise():
    kp, kd = Gains.from_interleaved([5.0, 0.5]).arguments()
    assert (kp, kd) == (5.0, 0.5) and isinstance(kp, float) and isinstance(kd, float)
    assert Gains.from_interleaved([1, 2, 3, 4]).arguments() == ((1.0, 3.0), (2.0, 4.0))


@pytest.mark.parametrize("values, count", [((1.0, 2.0, 3.0), 3), ((), 0), ((7.0,), 1)])
def test_a_count_that_is_not_pairs_is_rejected_with_its_count(values, count):
    with pytest.raises(ValueError, match=rf"gains must be \(kp, kd\) pairs per drive, got {count} values"):
        Gains.from_interleaved(values)


def test_unequal_kp_and_kd_are_rejected():
    with pytest.raises(ValueError, match=r"one \(kp, kd\) pair per drive, got 2 kp and 1 kd values"):
        Gains.from_arrays([1.0, 2.0], [3.0])


def test_frozen():
    g = Gains.from_interleaved([1.0, 2.0])
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.kp = (3.0,)


def test_gain_pairs_checks_the_drive_count():
    from flexstab.options import gain_pairs

    assert gain_pairs([1.0, 2.0], 1) == (1.0, 2.0)
    assert gain_pairs([1.0, 2.0, 3.0, 4.0], 2) == ([1.0, 3.0], [2.0, 4.0])
    with pytest.raises(ValueError, match="2 \\(kp, kd\\) pairs expected, got 1"):
        gain_pairs([1.0, 2.0], 2)
