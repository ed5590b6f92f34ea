"""Adaptive step count of the extrapolated frozen-modal solve (``modal_floquet(extrapolate=True,
n_steps=None, rtol=...)``, ``stability.modal._adaptive_extrapolated``).

Oracle: systems with multipliers in closed form (periodic Lyapunov transforms of constant block
systems, ``test_implicit_floquet._block_system``), independent of ``stability``.  Claims: the
result's estimate meets ``rtol`` and bounds the true error; the ladder does not stop early (the
previous count misses ``rtol``); the work of every pass is counted; an unreachable ``rtol`` is one
clear error.  Rejected wrong answer: the raw midpoint solve at the chosen count (no extrapolation)
misses ``rtol``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from test_floquet_streamed import _known_system, _multiplier_error


@pytest.mark.slow
def test_adaptive_meets_rtol_and_bounds_the_true_error():
    from stability import floquet
    from stability.modal import ADAPTIVE_START_STEPS, modal_floquet

    wrapped, exact = _known_system()  # 32 states: ratio 3, N / 3 and N / 9 from the N factors
    rtol = 1e-6
    res = modal_floquet(wrapped, method="magnus2", extrapolate=True, rtol=rtol, accuracy="multipliers")
    assert res.error_estimate <= rtol
    assert _multiplier_error(res.multipliers, exact) <= res.error_estimate
    first = modal_floquet(wrapped, method="magnus2", extrapolate=True, n_steps=ADAPTIVE_START_STEPS,
                          accuracy="multipliers")
    assert first.error_estimate > rtol  # the refinement was needed ...
    assert res.n_steps > ADAPTIVE_START_STEPS and res.n_steps % ADAPTIVE_START_STEPS == 0
    assert res.n_evaluations == ADAPTIVE_START_STEPS + res.n_steps  # ... and its work is counted
    raw = floquet(wrapped, method="magnus2", n_steps=res.n_steps, error_estimate=False)
    assert _multiplier_error(raw.multipliers, exact) > rtol  # without the extrapolation: outside rtol


def test_adaptive_small_system_ratio_two():
    """8 states (``SMALL_N``): the ratio-2 extrapolation with its premise check, N / 2, N / 4, N / 8 solved."""
    from test_implicit_floquet import _block_system

    from stability.modal import modal_floquet
    from stability.periodic import PeriodicMatrixFunction

    P, exact = _block_system(4, 1.0, seed=5)
    res = modal_floquet(PeriodicMatrixFunction(P, 1.0), method="magnus2", extrapolate=True, rtol=1e-7,
                        accuracy="multipliers")
    assert res.error_estimate <= 1e-7
    assert _multiplier_error(res.multipliers, exact) <= res.error_estimate


@pytest.mark.slow
def test_adaptive_unreachable_rtol_is_one_clear_error():
    from stability import FloquetError
    from stability.modal import modal_floquet

    wrapped, _ = _known_system()
    with pytest.raises(FloquetError, match=r"estimate .* > rtol 1\.0e-13 at \d+ steps.*max_steps = 300"):
        modal_floquet(wrapped, method="magnus2", extrapolate=True, rtol=1e-13, max_steps=300)
    with pytest.raises(ValueError, match="rtol"):
        modal_floquet(wrapped, method="magnus2", extrapolate=True, rtol=math.nan)
