"""The plant protocols (``stability.gains.Plant`` / ``MeasuredPlant``) and the one tuning adapter
(``taguchi.tuning.GainObjective``) that dispatches on them."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from stability.gains import MeasuredPlant, Plant
from taguchi.tuning import GainObjective

DOUBLE = str(Path(__file__).parent / "models" / "double_pendulum.py")
OMEGA = 2 * math.pi
T = 2 * math.pi / OMEGA


@pytest.fixture(scope="module")
def double():
    from linearize.analysis import model_plant

    return model_plant(DOUBLE, OMEGA, samples=16)


def test_every_plant_satisfies_the_protocols(double):
    from flexstab.two_link import LabelledPlant
    from linearize.hill_plant import HillModelPlant
    from mbs_models.reduced import ReducedModel

    reduced = ReducedModel(omega=OMEGA)
    for plant in (reduced, double.linearization):
        assert isinstance(plant, Plant) and not isinstance(plant, MeasuredPlant), type(plant)
    hill = HillModelPlant(double.linearization, double.orbit, harmonics=8)
    for plant in (double, hill, LabelledPlant(double.linearization, double.orbit)):
        assert isinstance(plant, Plant) and isinstance(plant, MeasuredPlant), type(plant)
    # the checks can fail: an object with neither method is no plant, and the adapter says so
    assert not isinstance(object(), (Plant, MeasuredPlant))
    with pytest.raises(ValueError, match=r"plant must provide with_gains\(kp, kd\) or spectral_measure"):
        GainObjective(object())


class _Oscillator:
    """``x'' + kd x' + kp x = 0`` with constant coefficients: the multipliers are ``exp(lambda T)``."""

    period = T

    def with_gains(self, kp, kd):
        A = np.array([[0.0, 1.0], [-float(kp), -float(kd)]])
        return _Constant(A)


class _Constant:
    period = T

    def __init__(self, A):
        self.A = A

    def __call__(self, t):
        return self.A


def test_a_plant_is_answered_by_the_spectral_radius_of_its_system():
    kp, kd = 9.0, 0.6
    lam = np.roots([1.0, kd, kp])
    exact = float(np.max(np.abs(np.exp(lam * T))))  # analytic: exp(-kd T / 2) for an underdamped pair
    y = GainObjective(_Oscillator(), {"n_steps": 64, "error_estimate": False})((kp, kd))
    assert y == pytest.approx(exact, rel=1e-8)
    # and the gains reach the plant in order: (kd, kp) swapped gives another radius
    assert abs(GainObjective(_Oscillator(), {"n_steps": 64, "error_estimate": False})((kd, kp)) - exact) > 1e-2


class _Measured(_Oscillator):
    """Both methods: its own response must win over the spectral radius of ``with_gains``."""

    def spectral_measure(self, kp, kd):
        return 0.125 + 0.0 * kp * kd


def test_a_measured_plant_is_answered_by_its_own_response():
    y = GainObjective(_Measured())((9.0, 0.6))
    assert y == 0.125
    assert abs(GainObjective(_Oscillator())((9.0, 0.6)) - 0.125) > 0.1  # the other rule gives another number


class _Recorder:
    def __init__(self):
        self.calls = []

    def spectral_measure(self, kp, kd):
        self.calls.append((kp, kd))
        return 0.5


def test_several_drives_receive_one_value_per_drive():
    rec = _Recorder()
    GainObjective(rec)((1.0, 2.0, 3.0, 4.0))
    GainObjective(rec)((5.0, 6.0))
    assert rec.calls == [((1.0, 3.0), (2.0, 4.0)), (5.0, 6.0)]
    with pytest.raises(ValueError, match="pairs per drive, got 3 values"):
        GainObjective(rec)((1.0, 2.0, 3.0))


def test_the_model_plants_take_interleaved_gains_through_the_adapter(double):
    """A two-drive model file: the adapter's value is the plant's at (kp1, kp2), (kd1, kd2); reading the
    vector as halves would evaluate other gains."""
    from linearize.hill_plant import HillModelPlant

    gains = (5.0, 0.5, 2.0, 0.2)
    y = GainObjective(double)(gains)
    assert y == double.spectral_measure([5.0, 2.0], [0.5, 0.2])
    assert abs(y - double.spectral_measure([5.0, 0.5], [2.0, 0.2])) > 1e-3
    hill = HillModelPlant(double.linearization, double.orbit, harmonics=8)
    # one value for every drive (a float) is the same as that value per drive
    assert hill.spectral_measure(5.0, 0.5) == hill.spectral_measure([5.0, 5.0], [0.5, 0.5])
