"""Exercise ``benchmarks/floquet_speed.py --quick`` (thin-script tier of STYLE.md).

Asserts what the benchmark measures is sound (both sides reach the 1e-8
accuracy target against the reference), not the timing itself, which depends
on the machine.
"""
from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "floquet_speed.py"


@pytest.mark.slow
def test_quick_benchmark(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("floquet_speed", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up in sys.modules
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        del sys.modules[spec.name]
        raise
    assert mod.main(["--quick", "--quiet", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "floquet_speed.json").read_text())
    assert data["quick"] and data["reference"] == "dop853"
    assert [c["case"] for c in data["cases"]] == mod.QUICK_CASES
    for c in data["cases"]:
        # the default method meets the accuracy target the baseline is held to
        assert c["default_max_rel_error"] <= mod.TARGET
        assert c["default_repeats"] >= 5
        assert c["best_method"] in mod.IVP_METHODS
        assert c["best_max_rel_error"] <= mod.TARGET
        assert c["ratio"] == pytest.approx(c["best_ms"] / c["default_ms"])
    assert data["total_ratio"] > 1.0
    out = capsys.readouterr().out
    assert "total:" in out and "T3 8pi" in out


def test_lean_baseline_P_is_the_papers_P():
    """The baseline's plainly written P(t) equals the model's (an honest baseline solves the same ODE)."""
    import math

    import numpy as np

    from mbs_models.reduced import ReducedModel

    spec = importlib.util.spec_from_file_location("floquet_speed_lean", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    try:
        spec.loader.exec_module(mod)
    finally:
        del sys.modules[spec.name]
    for _, k, kp, kd in mod.CASES:
        model = ReducedModel(k * math.pi, kp, kd)
        P = mod.lean_P(model.omega, kp, kd)
        for t in np.linspace(0.0, model.period, 7):
            ref = model(t)
            # both are a few flops from the same constants: rounding only
            assert np.max(np.abs(P(t) - ref)) <= 1e-14 * np.max(np.abs(ref))
