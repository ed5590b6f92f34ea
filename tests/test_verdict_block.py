"""The verdict block at the top of the study report and of ``study.json`` (flexstab.verdict_report)."""
from __future__ import annotations

import json
import math

import pytest

from flexstab.verdict_report import verdict_blocks, verdict_summary
from stability.verdict import judge

OMEGA = 2 * math.pi


def _write(tmp_path, name, rows):
    (tmp_path / name).write_text(json.dumps({"rows": rows}))


def _exudyn_row(tuned_rho=0.2998, whole=(0.9994342, 0.9994342, 0.3)):
    labels = ["axial 6", "axial 6", "hub"]
    return {"elements": 4, "target": 0.3, "tuned_kp": 9.7, "tuned_kd": 6.5, "tuned_dominant": tuned_rho,
            "verdict_uncontrolled": judge([13.64, 0.5], [1e-8, 1e-8], labels=["hub", "bending 1"]).to_dict(),
            "verdict_tuned": judge(list(whole), [1e-8] * 3, labels=labels).to_dict()}


def test_block_in_words_and_numbers(tmp_path):
    _write(tmp_path, "exudyn.json", [_exudyn_row()])
    _write(tmp_path, "table2.json", [{"omega": OMEGA, "moduli": [13.779, 0.57, 0.57, 0.07]}])
    _write(tmp_path, "validation.json", [{"diverged": False, "agrees": True, "multipliers": [{}, {}]}])
    s = verdict_summary(tmp_path, OMEGA)
    assert s["uncontrolled"]["verdict"] == "unstable" and "13.78" in s["uncontrolled"]["words"]
    assert s["tuned"]["verdict"] == "critical" and s["tuned"]["undamped_count"] == 2
    # a tuned response below the spectral radius is said in words, with the mode
    assert "axial 6 does not decay that fast" in s["tuned"]["words"]
    assert s["nonlinear_check"]["verdict"] == "confirmed"
    table = verdict_blocks(s)[1]
    assert [r[1] for r in table["rows"]] == ["unstable", "critical", "confirmed"]


def test_two_link_row_states_response_and_spectral_radius(tmp_path):
    """The two-link arm at its four-gain optimum: drive-mode response 0.300 beside the whole loop's 0.557
    (axial 9, 22.1 kHz) -- values of the two_link stage's JSON, said in words."""
    v = judge([0.5573, 0.5573, 0.3001, 0.3001], [2.5e-5] * 4, labels=["axial 9", "axial 9", "shoulder", "shoulder"],
              frequencies=[22100.0, 22100.0, 0.5, 0.5]).to_dict()
    _write(tmp_path, "two_link.json", [{"elements": 2, "tuned_gains": [15.0, 8.9355, 7.1387, 1.4443],
                                        "tuned": {"dominant_modulus": 0.3001, "whole_spectrum": {"verdict_detail": v}}}])
    s = verdict_summary(tmp_path, OMEGA)
    t = s["two_link_tuned"]
    assert t["tuned_response"] == 0.3001 and t["spectral_radius"] == 0.5573 and t["spectral_radius_mode"] == "axial 9"
    assert "decay at 0.3 per period" in t["words"] and "axial 9 at 22.1 kHz decays at 0.557" in t["words"]
    rows = verdict_blocks(s)[1]["rows"]
    assert [r[0] for r in rows] == ["**uncontrolled**", "**tuned**", "**tuned (two-link arm)**", "**nonlinear check**"]
    # a two-link stage that did not run in this study gives no row
    assert "two_link_tuned" not in verdict_summary(tmp_path, OMEGA, computed={"exudyn"})


def test_block_does_not_guess(tmp_path):
    _write(tmp_path, "exudyn.json", [_exudyn_row(tuned_rho=0.3, whole=(0.3, 0.2, 0.1))])
    _write(tmp_path, "validation.json", [{"diverged": False, "agrees": False, "multipliers": [{}]}])
    s = verdict_summary(tmp_path, OMEGA, computed={"exudyn", "validation"})
    assert s["tuned"]["verdict"] == "asymptotically stable" and "does not decay" not in s["tuned"]["words"]
    assert s["nonlinear_check"]["verdict"] == "check failed"
    # a stage that did not run in this study: "not computed", even if an old file is there
    s2 = verdict_summary(tmp_path, OMEGA, computed={"exudyn"})
    assert s2["nonlinear_check"]["verdict"] is None and "not computed" in s2["nonlinear_check"]["words"]
    _write(tmp_path, "validation.json", [{"diverged": True, "reason": "Newton failed at t = 3.1"}])
    assert verdict_summary(tmp_path, OMEGA)["nonlinear_check"]["verdict"] == "diverged"


@pytest.mark.slow
def test_quick_study_opens_with_the_verdict(tmp_path):
    from flexstab.config import StudyConfig
    from flexstab.study import StudyOptions, run_study

    run_study(StudyConfig(), StudyOptions(out=tmp_path, quick=True, stages=("table2", "exudyn"), progress=False,
                                          jobs=1))
    md = (tmp_path / "report.md").read_text()
    sections = [line for line in md.splitlines() if line.startswith("## ")]
    assert sections[0] == "## Verdict"
    d = json.loads((tmp_path / "study.json").read_text())
    v = d["verdict"]
    # uncontrolled: the paper's Table 2 at 2 pi prints |rho1| = 13.7797 for the reduced model
    assert v["uncontrolled"]["verdict"] == "unstable"
    assert v["uncontrolled"]["reduced_model_spectral_radius"] == pytest.approx(13.7797, rel=1e-4)
    # tuned: the undamped mesh leaves the whole loop critical although the hub mode is at rho_d
    assert v["tuned"]["tuned_response"] == pytest.approx(0.3, abs=1e-3)
    assert v["tuned"]["verdict"] == "critical" and v["tuned"]["spectral_radius"] > 0.999
    assert v["nonlinear_check"]["verdict"] is None  # the validation stage did not run
