"""scripts/compare_models.py in its fast mode (2 elements, Omega = 2 pi).

Oracle: the paper's Table 3 (|rho_1| = 0.3 at Omega = 2 pi with its gains,
p. 489) for the reduced and the Exudyn models, and the direct Exudyn
monodromy against the linearisation.
"""
import importlib.util
import json
import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "compare_models.py"


def test_compare_models_fast(tmp_path):
    spec = importlib.util.spec_from_file_location("compare_models", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--fast", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "models.json").read_text())
    md = (tmp_path / "models.md").read_text()
    rows = data["rows"]
    assert [(r["kp"], r["kd"]) for r in rows] == [(0.0, 0.0), (37.1617, 29.241)]
    ctrl = rows[1]
    assert ctrl["reduced"] == pytest.approx(0.3, rel=0.02)
    assert ctrl["exudyn_orbit"] == pytest.approx(0.3, rel=0.02)
    assert ctrl["exudyn_orbit"] == pytest.approx(ctrl["direct"], rel=0.005)
    # uncontrolled: unstable in every model, linearisation and direct agree
    unc = rows[0]
    assert unc["exudyn_orbit"] > 1 and unc["reduced"] > 1
    assert unc["exudyn_orbit"] == pytest.approx(unc["direct"], rel=0.005)
    # every number in the table comes from the JSON
    assert f"{ctrl['exudyn_orbit']:.6g}" in md and f"{unc['direct']:.6g}" in md
