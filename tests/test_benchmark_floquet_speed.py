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
