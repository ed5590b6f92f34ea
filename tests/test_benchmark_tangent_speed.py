"""``benchmarks/tangent_speed.py`` in its fast mode (2 elements): what it compares is sound.

Not the timings: the coloured route must equal the per-column differences to round-off
(same rule, steps and function values per entry: <= 10 eps / h relative, see
tests/test_orbit_jacobians.py), Exudyn's route to the per-column differences' own
error (Richardson O(h^4), measured 2e-12 at 8 elements; 1e-9 bounds it with margin and
still rejects a forward-difference Jacobian, off by ~1e-7).
"""
from __future__ import annotations


import numpy as np
import pytest

@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("tangent_speed")


def test_fast_mode_compares_equal_jacobians(bench):
    from linearize.periodic_orbit import RICHARDSON_STEP

    row = bench.measure(2)
    diff = row["max_rel_diff_to_per_column"]
    roundoff = 10 * np.finfo(float).eps / RICHARDSON_STEP
    assert diff["coloured_K"] <= roundoff and diff["coloured_C"] <= roundoff
    assert diff["exudyn_K"] <= 1e-9 and diff["exudyn_C"] <= 1e-9
    assert set(row["cpu_s"]) == {"per_column", "coloured", "exudyn"}
    assert row["colours"] < row["ode2"]
