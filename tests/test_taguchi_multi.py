"""Taguchi tuning over any number of gains, model-free.

Oracles: objectives with a known solution written here (a separable quadratic
whose only point at the target is a chosen interior point), the array sizes of
Taguchi's standard tables, and, for two gains, the reduced single-link model
with the independent ``paper`` Floquet method.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from taguchi.direct import direct_tune
from taguchi.tuning import TuningConfig, default_factor_names, taguchi_tune

RHO_D = 0.3


class Bowl:
    """``y(g) = rho_d + sum_i a_i (g_i - c_i)^2``: the target is reached at ``g = c`` only."""

    def __init__(self, centre, weights):
        self.c = np.asarray(centre, dtype=float)
        self.a = np.asarray(weights, dtype=float)
        self.calls = 0

    def __call__(self, gains):
        self.calls += 1
        g = np.asarray(gains, dtype=float)
        return RHO_D + float(np.sum(self.a * (g - self.c) ** 2))

    def radius(self, tol):
        """|g_i - c_i| <= sqrt(tol / a_i) whenever y(g) - rho_d <= tol (each term is <= the sum)."""
        return np.sqrt(tol / self.a)


def _within(bowl, gains, tol):
    return bool(np.all(np.abs(np.asarray(gains) - bowl.c) <= bowl.radius(tol)))


@pytest.mark.parametrize("n, runs", [(4, 9), (6, 18), (8, 27)])
def test_known_optimum_many_factors(n, runs):
    rng = np.random.default_rng(n)
    ranges = tuple((0.0, float(hi)) for hi in rng.uniform(20.0, 60.0, n))
    centre = [hi * f for (_, hi), f in zip(ranges, rng.uniform(0.15, 0.85, n))]  # off the level grid
    bowl = Bowl(centre, 1.0 / np.array([hi for _, hi in ranges]) ** 2)
    cfg = TuningConfig(target=RHO_D, ranges=ranges, max_evaluations=3000)
    res = taguchi_tune(bowl, cfg)
    assert res.converged, res.message
    assert res.names == default_factor_names(n)
    tol = cfg.effective_tolerance
    assert _within(bowl, res.gains, tol)
    # a wrong answer is rejected: a point just outside the bound in one factor
    wrong = np.array(res.gains)
    wrong[0] = bowl.c[0] + 1.01 * bowl.radius(tol)[0]
    assert not _within(bowl, wrong, tol)
    # the arrays of Taguchi's standard tables: L9 (<= 4 factors), L18 (<= 7), L27 (<= 13)
    assert all(len(it.design) == runs for it in res.iterations)
    assert res.evaluations == bowl.calls == sum(runs + 1 for _ in res.iterations)
    # every gain of every run stays in the user's ranges (Eq. 12)
    for it in res.iterations:
        for row in it.design:
            assert all(lo <= g <= hi for g, (lo, hi) in zip(row, ranges))


def test_four_factor_json_names_and_single_drive_keys_unchanged():
    bowl = Bowl([10.0, 5.0, 3.0, 1.0], [1e-3] * 4)
    res = taguchi_tune(bowl, TuningConfig(ranges=((0, 40),) * 4, max_evaluations=2000))
    d = res.to_dict()
    assert d["names"] == ["kp1", "kd1", "kp2", "kd2"]
    assert [d[k] for k in d["names"]] == list(res.gains)
    assert "kp1_range" in d["iterations"][0] and "kp_range" not in d["iterations"][0]
    with pytest.raises(AttributeError, match="gains"):
        res.kp  # noqa: B018  (several drives: no single kp)


def test_two_gains_explicit_ranges_identical_to_kp_kd_ranges():
    bowl = Bowl([17.3, 11.1], [1e-3, 2e-3])
    a = taguchi_tune(bowl, TuningConfig(kp_range=(0, 60), kd_range=(0, 40)))
    b = taguchi_tune(bowl, TuningConfig(ranges=((0, 60), (0, 40))))
    assert a.gains == b.gains and a.evaluations == b.evaluations
    assert [it.responses for it in a.iterations] == [it.responses for it in b.iterations]
    d = a.to_dict()
    assert (d["kp"], d["kd"]) == (a.kp, a.kd) == a.gains
    assert d["iterations"][0]["kp_range"] == [0.0, 60.0]


def test_reduced_model_two_gains_still_reach_table3_target():
    from mbs_models.reduced import ReducedModel
    from stability import floquet
    from taguchi.tuning import GainObjective

    model = ReducedModel(omega=4 * math.pi)
    res = taguchi_tune(GainObjective(model), TuningConfig(target=RHO_D))
    assert res.converged and len(res.iterations[0].design) == 9
    # re-checked with the adaptive method (step doubling to rtol 1e-9), not the loop's fixed
    # 256 steps: tuner tolerance 1e-3 rho_d plus its certified error estimate
    check = floquet(model.with_gains(res.kp, res.kd))
    assert abs(check.spectral_radius - RHO_D) <= 1e-3 * RHO_D + check.error_estimate


@pytest.mark.parametrize("method", ["nelder-mead", "differential-evolution"])
def test_direct_optimisers_four_factors(method):
    bowl = Bowl([12.0, 7.0, 20.0, 3.0], [1 / 40**2] * 4)
    cfg = TuningConfig(ranges=((0, 40),) * 4, max_evaluations=5000)
    res = direct_tune(bowl, cfg, method)
    assert res.converged and _within(bowl, res.gains, cfg.effective_tolerance)
    assert res.evaluations == bowl.calls


@pytest.mark.parametrize("kwargs, word", [
    ({"ranges": ()}, "ranges"),
    ({"ranges": ((0, 1), (2, 1))}, "kd range"),
    ({"ranges": ((0, 1),) * 3, "names": ("a", "b")}, "names"),
    ({"ranges": ((0, 1),) * 2, "names": ("a", "a")}, "names"),
])
def test_bad_multi_factor_config(kwargs, word):
    with pytest.raises(ValueError, match=word):
        TuningConfig(**kwargs)


class _Oscillators:
    """Two PD-controlled unit oscillators y_i'' + kd_i y_i' + (1 + kp_i) y_i = 0 and one undamped
    (frequency 3): constant coefficients, so the multipliers are exp(lambda T) exactly."""

    def __init__(self, kp=(0.0, 0.0), kd=(0.0, 0.0)):
        self.kp, self.kd = tuple(kp), tuple(kd)

    def with_gains(self, kp, kd):
        return _Oscillators(kp, kd)

    def matrices(self):
        K = np.diag([1.0 + self.kp[0], 1.0 + self.kp[1], 9.0])
        C = np.diag([self.kd[0], self.kd[1], 0.0])
        return K, C

    @property
    def period(self):
        return 2 * math.pi

    def __call__(self, t):
        K, C = self.matrices()
        return np.block([[np.zeros((3, 3)), np.eye(3)], [-K, -C]])

    def exact(self):
        K, C = self.matrices()
        lam = np.linalg.eigvals(np.block([[np.zeros((3, 3)), np.eye(3)], [-K, -C]]))
        return np.abs(np.exp(lam * self.period))


def test_drive_gain_objective_pairs_and_unit_circle():
    from taguchi.tuning import GainObjective

    gains = (3.0, 0.4, 1.0, 0.1)  # (kp1, kd1, kp2, kd2)
    plant = _Oscillators()
    exact = _Oscillators((3.0, 1.0), (0.4, 0.1)).exact()
    # magnus6 on constant coefficients is exact up to the matrix exponential: round-off only
    opts = {"n_steps": 64, "error_estimate": False}
    assert GainObjective(plant, opts)(gains) == pytest.approx(1.0, abs=1e-9)  # the undamped oscillator
    damped = np.max(exact[np.abs(exact - 1.0) > 1e-3])
    assert GainObjective(plant, opts, unit_circle_tolerance=2e-3)(gains) == pytest.approx(damped, rel=1e-9)
    # the pairs are (kp, kd) per drive: swapping the drives' roles changes the answer
    swapped = np.max(np.abs(np.exp(np.linalg.eigvals(np.array([[0, 1], [-(1 + 0.4), -3.0]])) * 2 * math.pi)))
    assert abs(swapped - damped) > 1e-3
    with pytest.raises(ValueError, match="pairs"):
        GainObjective(plant, opts)((1.0, 2.0, 3.0))
