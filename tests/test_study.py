"""The one-command study: report tables, paper claims, runs and resuming."""
from __future__ import annotations

import json
import math
import re
from html.parser import HTMLParser

import pytest

from flexstab.cli import main as cli_main
from flexstab.config import StudyConfig
from flexstab.study import StudyOptions, render_report, run_study
from _link_oracle.exudyn_link import ExudynLinkConfig
from _link_oracle.link_orbit import find_periodic_orbit

from mbs_models.parameters import ManipulatorParameters

from _model_bounds import model_difference_bound  # tests/ helper

#: A user's own link: not the paper's, so no printed value applies to it.
USER_LINK = ManipulatorParameters(length=0.6, tip_mass=0.3)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    return run_study(StudyConfig(elements=2),
                     StudyOptions(out=out, quick=True, stages=("table2", "table3", "exudyn"), progress=False))


@pytest.fixture(scope="module")
def user_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("user")
    return run_study(StudyConfig(manipulator=USER_LINK, elements=2),
                     StudyOptions(out=out, quick=True, stages=("table2", "table3"), progress=False))


# ----------------------------------------------------------------------------- table structure
def gfm_cells(line: str) -> list[str]:
    """Cells of a GitHub-flavoured Markdown table row (a pipe escaped as \\| stays in its cell).

    Written here, independently of flexstab.report, following the GFM spec (section 4.10, tables).
    """
    body = line.strip()
    body = body[1:] if body.startswith("|") else body
    body = body[:-1] if body.endswith("|") and not body.endswith("\\|") else body
    cells, cur, i = [], "", 0
    while i < len(body):
        if body[i] == "\\" and i + 1 < len(body):
            cur += body[i: i + 2]
            i += 2
            continue
        if body[i] == "|":
            cells.append(cur.strip())
            cur = ""
        else:
            cur += body[i]
        i += 1
    cells.append(cur.strip())
    return cells


def markdown_tables(md: str) -> list[list[list[str]]]:
    tables, cur = [], []
    for line in md.splitlines() + [""]:
        if line.startswith("|"):
            cur.append(gfm_cells(line))
        elif cur:
            tables.append(cur)
            cur = []
    return tables


def check_markdown_tables(md: str) -> int:
    tables = markdown_tables(md)
    for t in tables:
        header, sep, rows = t[0], t[1], t[2:]
        assert all(set(c) <= set("-:") and c for c in sep), sep
        assert len(sep) == len(header), (header, sep)
        for r in rows:
            assert len(r) == len(header), f"{len(r)} cells under {len(header)} headings: {header} / {r}"
    return len(tables)


class _TableCounter(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tables: list[list[tuple[str, int]]] = []
        self._row = None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._row.append(tag)

    def handle_endtag(self, tag):
        if tag == "tr" and self._row is not None:
            self.tables[-1].append(self._row)
            self._row = None


def check_html_tables(page: str) -> int:
    p = _TableCounter()
    p.feed(page)
    for t in p.tables:
        header = t[0]
        assert header and set(header) == {"th"}
        for r in t[1:]:
            assert set(r) == {"td"} and len(r) == len(header), (header, r)
    return len(p.tables)


def test_table_checks_reject_a_split_heading():
    """The old report's Table 3 heading: 'max|rho|' unescaped splits into extra cells."""
    bad = "| Omega | max|rho| (paper method) | evals |\n|---|---|---|\n| 2pi | 0.30018 | 100 |\n"
    with pytest.raises(AssertionError):
        check_markdown_tables(bad)
    bad_html = "<table><tr><th>a</th><th>b</th></tr><tr><td>1</td></tr></table>"
    with pytest.raises(AssertionError):
        check_html_tables(bad_html)


@pytest.mark.slow
@pytest.mark.parametrize("which", ["study", "user_study"])
def test_every_table_row_has_as_many_cells_as_headings(which, request):
    res = request.getfixturevalue(which)
    md = res.report_md.read_text()
    page = res.report_html.read_text()
    n_md = check_markdown_tables(md)
    n_html = check_html_tables(page)
    assert n_md == n_html >= 2
    assert "max\\|ρ\\|" in md  # the heading that used to split is escaped, not renamed away


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
        assert f"{row['reference_gains_dominant_exudyn']:.5f}" in md
        # model agreement (not an oracle): Exudyn vs reduced within what separates the two
        # models, the orbit's deflection (tests/_model_bounds.py)
        orbit = find_periodic_orbit(config=ExudynLinkConfig(elements=row["elements"], omega=row["omega"]),
                                    samples=16, verify=False)
        bound = model_difference_bound(orbit, row["reference_gains_dominant_reduced"])
        assert abs(math.log(row["reference_gains_dominant_exudyn"] / row["reference_gains_dominant_reduced"])) <= bound


# ----------------------------------------------------------------------------- paper claims
PAPER_CLAIMS = ("printed", "paper Table 3 gains", "Table 2 of the paper", "Liouville printed")


def test_paper_claims_only_for_the_papers_manipulator(study, user_study):
    paper_md = study.report_md.read_text()
    assert all(c in paper_md for c in ("printed", "Liouville printed")), "the paper's report compares"
    for res in (user_study,):
        for page in (res.report_md.read_text(), res.report_html.read_text()):
            found = [c for c in PAPER_CLAIMS if c.lower() in page.lower()]
            assert not found, f"paper claims in a user's report: {found}"
            assert "user-defined manipulator" in page and "length = 0.6 m" in page


def test_table2_claim_is_computed_not_written():
    """The 'to the printed digits' sentence only appears when the digits do agree."""
    from flexstab.paper_tables import table2_blocks, table2_rows

    rows = table2_rows(omegas=[2 * math.pi])
    assert not rows[0]["dominant_within_printed_digits"]  # 13.779043 vs printed 13.7797
    body = json.dumps(table2_blocks(rows))
    assert "to the printed digits" not in body and "agree with the printed ones within" in body


def test_user_link_rows_carry_no_printed_values(user_study):
    for name in ("table2", "table3"):
        for row in json.loads((user_study.out / f"{name}.json").read_text())["rows"]:
            assert not [k for k in row if k.startswith("printed")]
    # the reference gains of the Exudyn stage and the transients: tuned on the user's link, not printed
    from flexstab.study import _reference_gains

    kp, kd, source = _reference_gains(StudyConfig(manipulator=USER_LINK, elements=2),
                                      StudyOptions(out=user_study.out, quick=True))
    row = json.loads((user_study.out / "table3.json").read_text())["rows"][0]
    assert (kp, kd) == (row["kp"], row["kd"]) and source == "Taguchi on the reduced model (table3.json)"
    kp, kd, source = _reference_gains(StudyConfig(), StudyOptions(out=user_study.out, quick=True))
    assert (kp, kd, source) == (37.1617, 29.2410, "paper Table 3 gains")


# ----------------------------------------------------------------------------- runs, resume, progress
def test_study_json_and_manifest(study):
    s = json.loads((study.out / "study.json").read_text())
    assert set(s["stages"]) == {"table2", "table3", "exudyn"}
    m = json.loads((study.out / "manifest.json").read_text())
    assert m["config"]["manipulator"] == ManipulatorParameters().to_dict()
    for name, stage in s["stages"].items():
        doc = json.loads((study.out / stage["json"]).read_text())
        assert doc["study"]["config_hash"] == m["config_hash"] == s["config_hash"]
        assert doc["study"]["inputs_hash"] == m["stages"][name]["inputs_hash"]


def test_stage_records_carry_wall_and_cpu_and_the_exudyn_stage_ran_beside(study):
    """The fixture runs with the default jobs=2: exudyn in the second process, its CPU counted there."""
    m = json.loads((study.out / "manifest.json").read_text())
    for name in ("table2", "table3", "exudyn"):
        rec = json.loads((study.out / f"{name}.stage.json").read_text())
        assert rec["elapsed"] > 0 and rec["cpu"] >= 0
        assert m["stages"][name]["cpu"] == rec["cpu"]
    # the Exudyn stage does real work (orbit, linearisation, ~90 Floquet evaluations): a CPU time of ~0
    # would mean the second process's time was not measured
    assert json.loads((study.out / "exudyn.stage.json").read_text())["cpu"] > 0.5
    assert list(m["stages"]) == ["table2", "table3", "exudyn"]  # report order = stage order


def test_quick_exudyn_tuning_is_checked_at_the_full_step_count(study):
    """--quick tunes with half the propagator steps; the reported multiplier is at the full count.

    magnus2 is second order, so the loop's error at the tuned gains is ~ 4/3 |r_n - r_2n| (the
    recorded estimate); it must stay below a quarter of the tuning tolerance (else the stage tunes
    again at the full count), so the full-count value is within tolerance + estimate of rho_d.
    """
    row = json.loads((study.out / "exudyn.json").read_text())["rows"][0]
    tol = 1e-3 * row["target"]  # TuningConfig's default tolerance
    assert row["tuning_propagator_steps"] == row["propagator_steps"] // 2
    assert row["tuning_step_doubling_estimate"] is not None and row["tuning_step_doubling_estimate"] <= tol / 4
    assert abs(row["tuned_dominant"] - row["target"]) <= tol + row["tuning_step_doubling_estimate"]


@pytest.mark.parametrize("jobs", [0, -1, True, 1.5])
def test_bad_jobs(jobs, tmp_path):
    with pytest.raises(ValueError, match="jobs"):
        run_study(StudyConfig(), StudyOptions(out=tmp_path, stages=("table2",), progress=False, jobs=jobs))


def test_cli_jobs_zero_is_one_line_exit_2(tmp_path, capsys):
    assert cli_main(["study", "--quick", "--stages", "table2", "--jobs", "0", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--jobs" in err[0]


def test_resume_reuses_finished_stages_and_says_so(tmp_path):
    opts = StudyOptions(out=tmp_path, quick=True, stages=("table2",), progress=False)
    first = run_study(StudyConfig(), opts)
    assert first.stages["table2"]["status"] == "computed"
    again = run_study(StudyConfig(), opts)
    assert again.stages["table2"]["status"] == "reused"
    md = again.report_md.read_text()
    assert "reused from the run finished at" in md and "Reused from an earlier run" in md
    # another input (the target) changes the hash: recomputed, not reused
    other = run_study(StudyConfig(target=0.25), opts)
    assert other.stages["table2"]["status"] == "computed"
    # a stage file changed by hand is not reused either
    doc = json.loads((tmp_path / "table2.json").read_text())
    doc["rows"][0]["moduli"][0] = 1.0
    (tmp_path / "table2.json").write_text(json.dumps(doc))
    assert run_study(StudyConfig(target=0.25), opts).stages["table2"]["status"] == "computed"


def test_report_never_mixes_runs(tmp_path):
    user = StudyConfig(manipulator=USER_LINK)
    run_study(StudyConfig(), StudyOptions(out=tmp_path, quick=True, stages=("table2",), progress=False))
    res = run_study(user, StudyOptions(out=tmp_path, quick=True, stages=("table2",), progress=False))
    md = res.report_md.read_text()
    assert "length = 0.6 m" in md and "length = 0.9 m" not in md
    # a stage file of another run put beside the report is detected when rendering
    doc = json.loads((tmp_path / "table2.json").read_text())
    doc["rows"][0]["moduli"][0] *= 2
    (tmp_path / "table2.json").write_text(json.dumps(doc))
    with pytest.raises(RuntimeError, match="mix runs"):
        render_report(tmp_path)
    # a stage record from another configuration is refused too
    rec = json.loads((tmp_path / "table2.stage.json").read_text())
    rec["config_hash"] = "0" * 12
    (tmp_path / "table2.stage.json").write_text(json.dumps(rec))
    with pytest.raises(RuntimeError, match="another configuration"):
        render_report(tmp_path)


def test_progress_lines_when_stderr_is_not_a_terminal(tmp_path, capsys):
    assert cli_main(["study", "--quick", "--stages", "table2", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert any(re.fullmatch(r"study: \[1/1\] table2 started", line) for line in err), err
    assert any(re.fullmatch(r"study: \[1/1\] table2 finished in \d+\.\d s", line) for line in err), err
    assert cli_main(["study", "--quick", "--stages", "table2", "--out", str(tmp_path)]) == 0
    assert any("table2 reused" in line for line in capsys.readouterr().err.splitlines())


def test_section_titles_units_and_no_negative_zero(study):
    md = study.report_md.read_text()
    headings = [line[3:] for line in md.splitlines() if line.startswith("## ")]
    assert headings and not set(headings) & {"table2", "table3", "exudyn"}
    assert "length = 0.9 m" in md and "tip mass = 0.1 kg" in md
    assert "-0.00" not in md


def test_percent_has_no_negative_zero():
    from flexstab.report import percent

    assert percent(-1e-7) == "0.00 %" and percent(-1e-7, sign=True) == "0.00 %"
    assert percent(-0.0123, sign=True) == "-1.23 %" and percent(0.0123, sign=True) == "+1.23 %"


# ----------------------------------------------------------------------------- one Omega per study
@pytest.mark.slow
def test_study_omega_is_used_by_every_stage(tmp_path):
    """[study] omega = 4pi for a user's link: every table row is at 4pi, none at the paper's other Omegas."""
    cfg = StudyConfig(manipulator=USER_LINK, omega=4 * math.pi)
    res = run_study(cfg, StudyOptions(out=tmp_path, quick=True, stages=("table2", "table3"), progress=False))
    for name in ("table2", "table3"):
        rows = json.loads((res.out / f"{name}.json").read_text())["rows"]
        assert [r["omega"] for r in rows] == [pytest.approx(4 * math.pi, rel=1e-15)]


@pytest.mark.parametrize("command", ["floquet", "tune"])
def test_commands_take_omega_from_the_config(command, tmp_path, capsys):
    f = tmp_path / "w.toml"
    f.write_text('[study]\nomega = "4pi"\n')
    assert cli_main([command, "--config", str(f), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["omega"] == pytest.approx(4 * math.pi, rel=1e-15)
    assert cli_main([command, "--config", str(f), "--omega", "6pi", "--json"]) == 0  # --omega wins
    assert json.loads(capsys.readouterr().out)["omega"] == pytest.approx(6 * math.pi, rel=1e-15)


# ----------------------------------------------------------------------------- bad input
def test_unknown_stage(tmp_path):
    with pytest.raises(ValueError, match="unknown stage"):
        run_study(StudyConfig(), StudyOptions(out=tmp_path, stages=("nope",), progress=False))


def test_unwritable_out_exit_2(tmp_path, capsys):
    blocker = tmp_path / "f"
    blocker.write_text("x")
    assert cli_main(["study", "--quick", "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot be written" in err[0]


def test_markdown_escapes_pipes_and_html_needs_no_parsing():
    from flexstab.report import figure, table, text, to_html, to_markdown

    blocks = [text("a"), table(["x", "max|rho|"], [["1", "a|b"]]), figure("f.png", "cap")]
    md = to_markdown("t", [], [("s", blocks)])
    assert "| x | max\\|rho\\| |" in md and "| 1 | a\\|b |" in md
    page = to_html("t", [], [("s", blocks)])
    assert "<th>max|rho|</th>" in page and "<td>a|b</td>" in page
    with pytest.raises(ValueError, match="cells"):
        table(["a", "b"], [["1"]])


def test_interrupted_study_resumes_at_the_stage_it_stopped_in(tmp_path, monkeypatch):
    """Ctrl-C during table3: table2 is finished and recorded, so the rerun reuses it and computes table3."""
    import flexstab.study as study_mod

    def interrupted(cfg, opts):
        raise KeyboardInterrupt

    opts = StudyOptions(out=tmp_path, quick=True, stages=("table2", "table3"), progress=False)
    monkeypatch.setitem(study_mod.STAGES, "table3", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_study(StudyConfig(), opts)
    assert not (tmp_path / "report.md").exists()  # no report of a half run
    monkeypatch.undo()
    lines = []
    res = run_study(StudyConfig(), StudyOptions(out=tmp_path, quick=True, stages=("table2", "table3"),
                                                progress=False, log=lines.append))
    assert res.stages["table2"]["status"] == "reused" and res.stages["table3"]["status"] == "computed"
    assert any("table2 reused" in s for s in lines) and any("table3 started" in s for s in lines)


@pytest.mark.parametrize("jobs", [1, 2])
def test_exudyn_chains_run_in_processes_of_their_own(tmp_path, monkeypatch, jobs):
    """jobs=2: the Exudyn chain (exudyn -> validation) in one process, the two-link section in another,
    the other stages here; jobs=1: all here.  Stand-in stages record the process that ran them."""
    import os

    import flexstab.study as st

    def stand_in(name):
        def stage(cfg, opts):
            (opts.out / f"{name}.json").write_text(json.dumps({"pid": os.getpid()}))
            return {"json": f"{name}.json", "title": name, "blocks": []}
        return stage

    names = ("table2", "exudyn", "validation", "two_link")
    for name in names:
        monkeypatch.setitem(st.STAGES, name, stand_in(name))
    run_study(StudyConfig(), StudyOptions(out=tmp_path, stages=names, progress=False, jobs=jobs))
    pid = {n: json.loads((tmp_path / f"{n}.json").read_text())["pid"] for n in names}
    assert pid["table2"] == os.getpid()
    if jobs == 1:
        assert set(pid.values()) == {os.getpid()}
    else:
        assert pid["exudyn"] == pid["validation"] != os.getpid()
        assert pid["two_link"] not in (os.getpid(), pid["exudyn"])
