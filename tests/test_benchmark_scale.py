"""``benchmarks/scale.py``: the growth-exponent fit and one worker run on the coarsest mesh.

The fit is checked against exact power laws (it must recover the exponent and
tell two laws apart); the worker run checks what the benchmark measures is
sound (orbit residual within its tolerance, implicit multipliers equal to the
dense ones), not the timings.
"""
from __future__ import annotations

import math

import pytest

@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("scale")


def _records(p: float, c: float = 0.01):
    return [{"elements": e, "total_cpu_s": c * e**p, "pipeline_complete": True,
             "stages": {"orbit": {"cpu_s": c * e**p}, "linearization": {"cpu_s": 2 * c * e**1.0}}}
            for e in (4, 8, 16, 32, 64)]


def test_growth_exponent_recovers_power_laws(bench):
    exps = bench.growth_exponents(_records(2.5))
    assert abs(exps["orbit"] - 2.5) < 1e-12  # exact power law: least squares is exact
    assert abs(exps["total"] - 2.5) < 1e-12
    assert abs(exps["linearization"] - 1.0) < 1e-12
    assert math.isnan(exps["floquet_dense"])  # no data: no exponent, not 0
    assert abs(bench.growth_exponents(_records(3.0))["orbit"] - 2.5) > 0.4
    # a stage that did not finish (memory, time limit) does not enter its fit
    recs = _records(2.5)
    recs[-1]["stages"]["orbit"] = {"cpu_s": 1e6, "error": "not finished within 60 s"}
    assert abs(bench.growth_exponents(recs)["orbit"] - 2.5) < 1e-12


@pytest.mark.slow
def test_worker_on_four_elements(bench):
    rec = bench.worker(4, 16, 48, True, True, 4)
    assert rec["orbit_residual"] <= rec["orbit_tolerance"]
    assert rec["states"] > 0 and rec["peak_rss_mb"] > 0
    assert all(v["ok"] for v in rec["stages"].values())
    # certified implicit multipliers are multipliers of the same one-period map:
    # equal to the dense ones to the backward error 1e-10 times a small condition number
    assert rec["implicit"]["max_diff_to_dense"] <= 1e-8
    table = bench.markdown([rec], bench.growth_exponents([rec]))
    assert "| 4 |" in table
