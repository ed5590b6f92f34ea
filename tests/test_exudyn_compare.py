"""scripts/compare_models.py in its fast mode (2 elements, Omega = 2 pi).

Oracles: the paper's Table 3 (|rho_1| = 0.3 at Omega = 2 pi with its gains,
p. 489) for the reduced model; the direct Exudyn monodromy (Exudyn's own
integrator) for the Exudyn linearisation.  Reduced vs Exudyn is an agreement
between two models, bounded by what separates them (``_model_bounds``).
"""
import importlib.util
import json
import math
import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest

from _link_oracle.exudyn_link import ExudynLinkConfig
from _link_oracle.link_orbit import find_periodic_orbit

from _model_bounds import model_difference_bound  # tests/ helper

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "compare_models.py"
#: Half a unit of the 4th decimal: the gains of Table 3 are printed to 1e-4 and
#: d|rho|/dkp ~ 1e-2, so the reduced model meets the printed 0.3 to ~1e-6 (test_table2).
TABLE3_RESOLUTION = 1e-4
#: Half a unit of the fifth decimal: the README states the dominant multiplier of the direct monodromy
#: and of the linearisation at 2 pi with the Table 3 gains as 0.29981.
CLAIM_RESOLUTION = 5e-6


@pytest.mark.slow
def test_compare_models_fast_reduced_vs_table3_and_exudyn_vs_direct(tmp_path):
    spec = importlib.util.spec_from_file_location("compare_models", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--fast", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "models.json").read_text())
    md = (tmp_path / "models.md").read_text()
    rows = data["rows"]
    assert [(r["kp"], r["kd"]) for r in rows] == [(0.0, 0.0), (37.1617, 29.241)]
    ctrl, unc = rows[1], rows[0]
    # published value: Table 3, p. 489
    assert ctrl["reduced"] == pytest.approx(0.3, rel=TABLE3_RESOLUTION)
    # independent oracle for the Exudyn linearisation: Exudyn's own integrator.  The direct
    # monodromy carries the integrator's error over one period of the closed loop, which its
    # run reports as the shooting defect from the orbit state (relative to the elastic
    # deformation: ~1e-3 controlled, ~2e-2 uncontrolled at h = 1e-3, 2 elements).  The
    # linearisation route's own error is far smaller (test_linearize).  (This error bar
    # cannot tell the rigid-reference linearisation from the true-orbit one at 2 pi.)
    for row in (ctrl, unc):
        assert row["exudyn_orbit_mode"] == "hub"
        assert row["direct_closed_loop_defect"] < 0.05  # the integrator resolves the period
    # uncontrolled (13.6, no claim in the README): within the run's own reported error
    assert unc["exudyn_orbit"] == pytest.approx(unc["direct"], rel=unc["direct_closed_loop_defect"])
    # model agreement (reduced vs Exudyn), bounded by the orbit's deflection
    orbit = find_periodic_orbit(config=ExudynLinkConfig(elements=data["elements"]), samples=data["samples"],
                                verify=False)
    # controlled: the README's claim (direct monodromy 0.29981, the linearisation 0.29981) at the method's
    # error bound.  The direct monodromy's step error from a second run at half the step (generalised-alpha,
    # second order: the finer value is |d_h - d_h/2| / 3 off, the coarser one 4/3 |d_h - d_h/2|; GCI safety
    # 1.25), plus its finite-difference / Newton floor (scatter measured at h/4: 6.7e-6, where the Newton
    # error over epsilon overtakes the step error -- which is why the claim has five digits, not six).
    from _link_oracle.link_floquet import direct_monodromy

    half = abs(direct_monodromy(orbit, kp=ctrl["kp"], kd=ctrl["kd"], step_size=0.5e-3).dominant_multiplier)
    bound = 1.25 * 4.0 / 3.0 * abs(ctrl["direct"] - half)
    assert bound < 0.5 * CLAIM_RESOLUTION  # the direct route resolves the README's five digits (measured 5.7e-7)
    # the two routes agree to the claim (measured 6.2e-7: the linearisation's propagator error at the script's
    # step count, ~3e-7, is of the order of the direct route's step bound)
    assert abs(ctrl["exudyn_orbit"] - ctrl["direct"]) <= CLAIM_RESOLUTION
    assert abs(ctrl["exudyn_orbit"] - half) <= CLAIM_RESOLUTION
    # the check can fail: the reduced model's 0.299999 (a different model, 1.9e-4 away) is rejected
    assert abs(ctrl["reduced"] - ctrl["direct"]) > bound + CLAIM_RESOLUTION
    for row in (ctrl, unc):
        assert abs(math.log(row["exudyn_orbit"] / row["reduced"])) <= model_difference_bound(orbit, row["reduced"])
    # uncontrolled: unstable in every model
    assert unc["exudyn_orbit"] > 1 and unc["reduced"] > 1 and unc["direct"] > 1
    # every number in the table comes from the JSON
    assert f"{ctrl['exudyn_orbit']:.6g}" in md and f"{unc['direct']:.6g}" in md
