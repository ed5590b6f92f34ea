"""The refinement loop (``stability.refine.double_until``) against sequences with known errors.

Oracle: ``r_n = r + C n^-p`` has the exact error ``C n^-p``; the estimate ``4/3 |r_n - r_2n|`` bounds it
for every ``p >= 2`` (equality at ``p = 2``) and misses it for ``p = 1`` (the premise the docstring
states), which the last test shows.
"""
from __future__ import annotations

import math

import pytest

from stability.refine import double_until


@pytest.mark.parametrize("p", [2, 3, 4, 6])
def test_returned_count_meets_the_tolerance_by_the_true_error(p):
    C, tol = 5.0, 1e-6
    calls = []

    def value(n):
        calls.append(n)
        return 0.3 + C * n ** -p

    ref = double_until(value, 8, 1 << 20, tol)
    assert ref.converged and ref.estimate <= tol
    assert abs(ref.value - 0.3) <= tol * (1 + 1e-9)  # the true error of the returned count
    assert ref.n == calls[-2] and calls == [8 * 2**k for k in range(len(calls))]  # the coarser of the last pair
    assert ref.evaluations == len(calls)
    # the previous count did not meet it (the loop stops at the first count that does)
    assert (4 / 3) * abs(value(ref.n // 2) - value(ref.n)) > tol


def test_the_cap_stops_the_doubling_and_says_so():
    ref = double_until(lambda n: 1.0 / n, 4, 64, 1e-9)
    assert not ref.converged and ref.n == 64 and ref.evaluations == 5
    assert ref.estimate == pytest.approx(4 / 3 * abs(1 / 32 - 1 / 64))
    nothing = double_until(lambda n: 1.0, 64, 100, 1e-9)
    assert not nothing.converged and math.isnan(nothing.estimate) and nothing.n == 64
    above = double_until(lambda n: 1.0, 128, 100, 1e-9)  # a start above the cap: evaluated, not refined
    assert not above.converged and above.n == 128 and above.evaluations == 1


def test_a_first_order_sequence_breaks_the_premise():
    C, tol = 1.0, 1e-4
    ref = double_until(lambda n: C / n, 1, 1 << 30, tol)
    assert ref.converged
    assert abs(ref.value) > tol  # p = 1: 4/3 |r_n - r_2n| = (2/3) C / n under-reads the error C / n


@pytest.mark.parametrize("args", [(0, 8, 1e-3), (8.0, 16, 1e-3), (8, 16, 0.0), (8, 16, math.nan)])
def test_bad_arguments(args):
    with pytest.raises(ValueError):
        double_until(lambda n: 0.0, *args)


def test_the_tuning_step_choice_is_this_loop():
    """``flexstab.plants.propagator_choice`` on r_n = exact + c / n^2: with c = 320 the cap (4096) stops it
    at the pair (2048, 4096), estimate c / 2048^2 = 7.63e-5 > tol / 4 = 7.5e-5 (a warning, not converged);
    with c = 20 the first pair that meets it is (1024, 2048): c / 1024^2 = 1.9e-5, c / 512^2 = 7.63e-5 is above."""
    from dataclasses import dataclass

    from flexstab.plants import MAX_TUNING_STEPS, propagator_choice
    from taguchi.tuning import TuningConfig

    def fake(c):
        @dataclass(frozen=True)
        class Fake:
            n_steps: int = 256

            def spectral_measure(self, kp, kd):
                return 1.0 / (1.0 + 0.1 * (sum(kp) + sum(kd))) + c / self.n_steps ** 2

        return Fake()

    cfg = TuningConfig(target=0.3, ranges=((0.0, 10.0), (0.0, 10.0)))
    with pytest.warns(RuntimeWarning, match="MAX_TUNING_STEPS"):
        capped = propagator_choice(fake(320.0), cfg)
    assert not capped.converged and capped.n_steps == MAX_TUNING_STEPS == capped.plant.n_steps
    assert capped.error_estimate == pytest.approx(320.0 / 2048 ** 2, rel=1e-9)
    met = propagator_choice(fake(20.0), cfg)
    # first pair meeting 4/3 |r_n - r_2n| = c / n^2 <= 7.5e-5: n = 1024 (c / 512^2 = 7.63e-5 is above)
    assert met.converged and met.n_steps == 1024 and met.error_estimate == pytest.approx(20.0 / 1024 ** 2)
