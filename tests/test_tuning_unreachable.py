"""Tuning stops early, with one line, when rho_d is out of the search's reach (taguchi.tuning, module docstring).

Oracles: objectives written down in closed form whose range over the box is known (so whether rho_d is
reachable inside the ranges is known independently of the search), and, for the stalled case, a bisection
along the segment the message names (the response is continuous: a sign change of y - rho_d brackets a
point with y = rho_d).
"""
from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest

from taguchi.analysis import is_constant
from taguchi.tuning import (STATUS_BUDGET, STATUS_CONVERGED, STATUS_STALLED, STATUS_UNREACHABLE, TuningConfig,
                            taguchi_tune)

RANGES = ((0.0, 20.0), (0.0, 5.0), (0.0, 20.0), (0.0, 1.0))


def corner(g):
    """0.5 at the upper corner of RANGES, rising linearly inwards: min over the box 0.5 > rho_d = 0.3."""
    return 0.5 + 0.2 * sum(1.0 - v / hi for v, (_, hi) in zip(g, RANGES))


def _tune(objective, **kw):
    cfg = TuningConfig(target=0.3, ranges=RANGES, max_evaluations=600, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no raw RuntimeWarning (e.g. NaN ANOVA contributions) reaches the user
        return taguchi_tune(objective, cfg)


def _no_nan_contributions(res):
    for it in res.iterations:
        assert all(math.isfinite(c) for c in it.analysis.anova.contribution_percent), it.index
        assert math.isfinite(it.analysis.anova.error_contribution_percent)


def test_target_below_the_minimum_over_the_box_stops_early_naming_the_ranges_to_widen():
    """Every response in the box is >= 0.5 (closed form): rho_d = 0.3 cannot be reached.  Before, the search
    ran its whole budget (600 evaluations), 45 of 60 iterations on ranges collapsed onto the corner, with NaN
    contributions and a RuntimeWarning."""
    res = _tune(corner)
    assert res.status == STATUS_UNREACHABLE and not res.converged
    assert res.evaluations <= 100, res.evaluations  # a handful of experiments, not the budget
    assert res.gains == pytest.approx([hi for _, hi in RANGES])  # the best point is the corner ...
    assert res.spectral_radius == pytest.approx(0.5)
    msg = res.message
    assert "\n" not in msg and "out of reach inside the ranges" in msg and "above" in msg
    assert "widen the range of kp1, kd1, kp2, kd2" in msg and "kp1 = 20 (upper end)" in msg
    _no_nan_contributions(res)


def test_a_response_that_does_not_depend_on_the_gains_stops_after_one_experiment():
    res = _tune(lambda g: 0.7)
    assert res.status == STATUS_UNREACHABLE and res.evaluations == 9 and res.iterations == ()
    assert "every run of the last experiment gave the same response" in res.message


def test_a_stalled_search_says_that_rho_d_lies_inside_the_ranges_and_between_which_runs():
    """y = 0.28 on x1 <= 6, rising to 1 at x1 = 20 (continuous): the closest run of the first experiment is in the
    flat part and the windows shrink onto it, but rho_d = 0.3 is reached inside the box (x1 ~ 6.4).  The message
    names a run on the other side of rho_d; a bisection on the segment between the two finds y = rho_d."""
    def ramp(g):
        return 0.28 + 0.72 * max(0.0, g[0] - 6.0) / 14.0

    res = _tune(ramp)
    assert res.status == STATUS_STALLED and not res.converged
    assert res.evaluations <= 100
    assert "lies inside the ranges" in res.message and "start from ranges around both" in res.message
    other = [float(part.split(" = ")[1].split(" ")[0].rstrip(",)"))
             for part in res.message.split("the run at ")[1].split(" (max")[0].split(", ")]
    a, b = np.array(res.gains), np.array(other)
    assert (ramp(a) - 0.3) * (ramp(b) - 0.3) < 0  # opposite sides
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if (ramp(a + mid * (b - a)) - 0.3) * (ramp(a) - 0.3) > 0:
            lo = mid
        else:
            hi = mid
    assert ramp(a + hi * (b - a)) == pytest.approx(0.3, abs=1e-9)
    _no_nan_contributions(res)


def test_a_reachable_target_at_the_edge_of_the_ranges_still_converges():
    """The stopping rule must not give up on a reachable target: y = 0.5 - 0.2 x1 / 20 reaches 0.30005 at
    x1 = 19.995 (0.025 % inside the upper end), where the windows have to walk to."""
    cfg = TuningConfig(target=0.30005, ranges=RANGES, max_evaluations=600, tolerance=1e-6)
    res = taguchi_tune(lambda g: 0.5 - 0.2 * g[0] / 20.0 + 1e-3 * g[1], cfg)
    assert res.status == STATUS_CONVERGED, res.message
    assert abs(res.spectral_radius - 0.30005) <= 1e-6


def test_a_budget_too_small_for_a_reachable_target_is_still_budget_exhausted():
    res = taguchi_tune(lambda g: 0.5 - 0.2 * g[0] / 20.0 + 1e-3 * g[1],
                       TuningConfig(target=0.3123, ranges=RANGES, max_evaluations=20, tolerance=1e-9))
    assert res.status == STATUS_BUDGET


def test_is_constant_tells_an_experiment_without_information():
    assert is_constant([33.2] * 9) and not is_constant([33.2] * 8 + [33.2000001])


@pytest.mark.slow
def test_cli_tune_of_a_hopeless_double_pendulum_tuning_stops_with_one_line_and_exit_1(capsys):
    """The rigid double pendulum with ranges whose Taguchi windows shrink onto a corner (kp1 = 0, kd1 = 5,
    kp2 = 20, kd2 = 1; |rho| 0.278 there): before, 600 evaluations (179 s), 45 of 60 iterations on collapsed
    ranges, 'contribution ... nan %' and a raw RuntimeWarning.  Now: one line, exit 1, about a tenth of the
    evaluations, no NaN in the printed contributions."""
    from pathlib import Path

    from flexstab.cli import main

    model = Path(__file__).resolve().parent / "models" / "double_pendulum.py"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        rc = main(["tune", "--model", str(model), "--kp-range", "0", "20", "--kd-range", "0", "5",
                   "--range", "kd2=0,1"])
    out, err = capsys.readouterr()
    assert rc == 1
    lines = [ln for ln in err.splitlines() if ln.startswith("flexstab tune:")]
    assert len(lines) == 1 and "the search stalled" in lines[0], err
    assert not re.search(r"\bnan\b", out.lower())
    evaluations = int(out.split(" Floquet evaluations")[0].split("\n")[-1])
    assert evaluations <= 200
