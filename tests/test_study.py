"""The one-command study (issue 5, item 3): report tables against the JSON beside them."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from flexstab.cli import main as cli_main
from flexstab.config import StudyConfig
from flexstab.study import StudyOptions, run_study
from mbs_models.exudyn_link import ExudynLinkConfig
from mbs_models.orbit import find_periodic_orbit

from _model_bounds import model_difference_bound  # tests/ helper


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    res = run_study(StudyConfig(elements=2),
                    StudyOptions(out=out, quick=True, stages=("table2", "table3", "exudyn"), progress=False))
    return res


def test_report_written(study):
    assert study.report_md.exists() and study.report_html.exists()
    assert all("error" not in v for v in study.stages.values()), study.stages
    html = study.report_html.read_text()
    assert "<table>" in html and "table2" in html


def test_report_tables_match_json(study):
    md = study.report_md.read_text()
    t2 = json.loads((study.out / "table2.json").read_text())["rows"]
    for row in t2:
        assert f"{row['moduli'][0]:.6f}" in md  # dominant modulus as printed in the report
    t3 = json.loads((study.out / "table3.json").read_text())["rows"]
    for row in t3:
        assert f"{row['kp']:.4f}" in md and f"{row['spectral_radius_paper_method']:.5f}" in md
    ex = json.loads((study.out / "exudyn.json").read_text())["rows"]
    for row in ex:
        assert f"{row['printed_gains_dominant_exudyn']:.5f}" in md
        # model agreement (not an oracle): Exudyn vs reduced within what separates the two
        # models, the orbit's deflection (tests/_model_bounds.py)
        orbit = find_periodic_orbit(config=ExudynLinkConfig(elements=row["elements"], omega=row["omega"]),
                                    samples=16, verify=False)
        bound = model_difference_bound(orbit, row["printed_gains_dominant_reduced"])
        assert abs(math.log(row["printed_gains_dominant_exudyn"] / row["printed_gains_dominant_reduced"])) <= bound


def test_study_json_summary(study):
    s = json.loads((study.out / "study.json").read_text())
    assert set(s["stages"]) == {"table2", "table3", "exudyn"}
    for name, stage in s["stages"].items():
        assert (study.out / stage["json"]).exists()


def test_unknown_stage(tmp_path):
    with pytest.raises(ValueError, match="unknown stage"):
        run_study(StudyConfig(), StudyOptions(out=tmp_path, stages=("nope",), progress=False))


def test_unwritable_out_exit_2(tmp_path, capsys):
    blocker = tmp_path / "f"
    blocker.write_text("x")
    assert cli_main(["study", "--quick", "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot be written" in err[0]
