"""``flexstab study --model PATH.py``: a user's model through orbit, tuning, charts and validation.

Oracle: the rigid double pendulum's linearisation derived by hand and integrated by scipy
(DOP853, rtol 1e-12; tests/test_constrained_linearisation.py), independent of the package.
Tolerances: the tuning loop's Floquet evaluations are Richardson-extrapolated ``magnus2`` products
(4th order, :meth:`linearize.analysis.ModelPlant.floquet`), whose error is ~ 16/15 |r_n - r_2n|
asymptotically; 4/3 |r_n - r_2n| (the step-doubling numbers the study records) bounds it for any
observed order >= 2 (2^p / (2^p - 1) falls with p); twice that plus 1e-8 (orbit tolerance 1e-10,
oracle ~1e-10) bounds the difference from the oracle.
"""
from __future__ import annotations

import csv
import json
import math
import warnings

import numpy as np
import pytest

from flexstab.cli import main as cli_main
from test_constrained_linearisation import DOUBLE, double_pendulum_multipliers
from test_model_charts import dominant
from test_study import check_html_tables, check_markdown_tables

OMEGA = 2 * math.pi


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("model_study")
    rc = cli_main(["study", "--model", DOUBLE, "--quick", "--out", str(out)])
    assert rc == 0
    return out


@pytest.mark.slow
def test_uncontrolled_multipliers_equal_the_hand_linearisation(study):
    doc = json.loads((study / "floquet.json").read_text())
    assert doc["orbit_residual"] <= 1e-6 and doc["drives"] == ["shoulder", "elbow"]
    mu = np.array([complex(*z) for z in doc["floquet"]["multipliers"]])
    ref = double_pendulum_multipliers(OMEGA, (0.0, 0.0), (0.0, 0.0))
    # the estimate is of the moduli (accuracy="moduli", relative); the phases have their own
    tol = 2 * doc["floquet"]["error_estimate"] * np.max(np.abs(ref)) + 1e-8
    assert np.max(np.abs(np.sort(np.abs(mu)) - np.sort(np.abs(ref)))) <= tol
    assert np.max(np.abs(np.sort(np.abs(mu)) - np.sort(np.abs(ref)))) > 0  # not the oracle itself
    phase_tol = 2 * (doc["floquet"]["phase_error_estimate"] or 1e-4) + 1e-8
    assert np.max(np.abs(np.sort(np.angle(mu)) - np.sort(np.angle(ref)))) <= phase_tol
    rows = list(csv.DictReader((study / "multipliers.csv").open()))
    assert [r["case"] for r in rows] == ["uncontrolled"] * 4 + ["tuned"] * 4
    assert float(rows[0]["modulus"]) == pytest.approx(abs(mu[0]), rel=1e-15)


@pytest.mark.slow
def test_tuned_gains_reach_the_target_in_the_independent_check(study):
    doc = json.loads((study / "tuning.json").read_text())
    kp, kd, target, tol = doc["kp"], doc["kd"], doc["target"], doc["tolerance"]
    assert doc["tuning"]["status"] == "converged" and len(kp) == len(kd) == 2
    last = doc["propagator_passes"][-1]
    bound = tol + 2 * 4 / 3 * abs(last["check_2n"] - last["spectral_radius"]) + 1e-8
    assert abs(dominant(double_pendulum_multipliers(OMEGA, kp, kd)) - target) <= bound
    # the check can fail: the same gains on the other drives miss the target
    assert abs(dominant(double_pendulum_multipliers(OMEGA, kp[::-1], kd[::-1])) - target) > 10 * bound


@pytest.mark.slow
def test_report_charts_and_validation(study):
    md = (study / "report.md").read_text()
    for title in ("Periodic orbit and uncontrolled multipliers", "PD gains by Taguchi tuning", "Stability charts",
                  "Nonlinear validation"):
        assert f"## {title}" in md
    assert "Stage failed" not in md
    assert "at h = " in md and "at h =  s" not in md  # the measurement's own steps (step=None), not blank
    assert check_markdown_tables(md) >= 4 and check_html_tables((study / "report.html").read_text()) >= 4
    charts = json.loads((study / "charts.json").read_text())
    assert charts["charted_drive"] == "shoulder" and charts["fixed_kp"][1] == json.loads(
        (study / "tuning.json").read_text())["kp"][1]
    for f in charts["figures"]:
        assert (study / f.split("/")[-1]).stat().st_size > 0
    v = json.loads((study / "validation.json").read_text())
    assert v["agrees"] and len(v["multipliers"]) >= 2
    s = json.loads((study / "study.json").read_text())
    assert set(s["stages"]) == {"floquet", "tuning", "charts", "validation"}
    assert all(st["status"] == "computed" and st["cpu"] >= 0 for st in s["stages"].values())


@pytest.mark.parametrize("body, words", [
    ("def build(mbs, omega):\n    raise RuntimeError('no such body: arm')\n", "no such body: arm"),
    ("x = 1\n", "defines no function build"),
    ("def build(mbs, omega)\n    return []\n", "importing it failed"),
])
def test_broken_model_file_is_one_line_exit_2(tmp_path, capsys, body, words):
    f = tmp_path / "broken.py"
    f.write_text(body)
    assert cli_main(["study", "--model", str(f), "--quick", "--out", str(tmp_path / "o")]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("study: ")]
    assert len(err) == 1 and words in err[0], err  # besides the progress lines (stderr is not a terminal)


@pytest.mark.parametrize("argv, words", [
    (["--samples", "5"], "--samples must be an even integer"),
    (["--stages", "table2"], "--stages applies to the paper's study"),
    (["--jobs", "1"], "--jobs applies to the paper's study"),
])
def test_bad_options_are_one_line_exit_2(tmp_path, capsys, argv, words):
    assert cli_main(["study", "--model", DOUBLE, "--out", str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err


def test_inverted_gain_range_in_the_config_is_one_line(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[study]\nkp_range = [10.0, 1.0]\n")
    assert cli_main(["study", "--model", DOUBLE, "--config", str(cfg), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "kp_range" in err, err


@pytest.mark.slow
def test_tuning_whose_check_fails_is_check_failed_exit_1(tmp_path, monkeypatch, capsys):
    """Gain ranges [0, 1e-3] cannot move the rigid pendulum's multipliers (|rho| ~ 1) to rho_d = 0.3: the
    tuning stage computes, but its check fails (not converged; the separate evaluation ~0.7 from rho_d).
    Rejects a study that reports such a stage as "computed" and exits 0. To keep the test cheap the charts
    are stubbed out (they raise: stage "failed") and the nonlinear validation is a stand-in whose
    measurement does not confirm the prediction (``agrees`` false): that stage computes, so it must be
    "check failed" as well."""
    import flexstab.chart_runs as chart
    import flexstab.study as fs
    import validation.multipliers as vm
    import validation.plots as vp

    def stub(*a, **k):
        raise RuntimeError("stubbed out in this test")

    class NotConfirmed:
        def to_dict(self):
            return {"agrees": False}

    monkeypatch.setattr(chart, "model_charts", stub)
    monkeypatch.setattr(vm, "validate_model_multipliers", lambda *a, **k: NotConfirmed())
    monkeypatch.setattr(vp, "plot_multiplier_plane", lambda *a, **k: None)
    monkeypatch.setattr(fs, "validation_blocks", lambda *a, **k: [])
    cfg = tmp_path / "c.toml"
    cfg.write_text("[study]\nkp_range = [0.0, 0.001]\nkd_range = [0.0, 0.001]\n")
    out = tmp_path / "o"
    assert cli_main(["study", "--model", DOUBLE, "--quick", "--config", str(cfg), "--out", str(out)]) == 1
    stages = json.loads((out / "study.json").read_text())["stages"]
    assert stages["floquet"]["status"] == "computed"
    assert stages["tuning"]["status"] == "check failed", stages["tuning"]
    assert "tuning not converged" in stages["tuning"]["error"] and "separate evaluation" in stages["tuning"]["error"]
    assert stages["charts"]["status"] == "failed"
    assert stages["validation"]["status"] == "check failed" and "agrees = false" in stages["validation"]["error"]
    assert "**Check failed:** tuning not converged" in (out / "report.md").read_text()
    err = capsys.readouterr().err.splitlines()
    assert any(line.startswith("stage tuning check failed: ") for line in err)
    assert any(line.startswith("stage validation check failed: ") for line in err)


def test_tuning_check_failures_rule():
    """|check - rho_d| <= tolerance + estimate passes; beyond it, or not converged, fails (one line each)."""
    from flexstab.model_study import tuning_check_failures

    assert tuning_check_failures("converged", "", 0.3004, 2e-4, 0.3, 3e-4) == []
    assert len(tuning_check_failures("converged", "", 0.3006, 2e-4, 0.3, 3e-4)) == 1
    assert len(tuning_check_failures("budget exhausted", "x", 0.3, 0.0, 0.3, 3e-4)) == 1
    assert len(tuning_check_failures("converged", "", math.nan, 0.0, 0.3, 3e-4)) == 1  # NaN never passes


def test_other_warning_categories_reach_the_caller(tmp_path, monkeypatch):
    """A stage's warnings are recorded with simplefilter("always"); RuntimeWarnings go into the report,
    every other category must be passed on (they used to be dropped).  A stand-in ``analyze`` warns
    and fails (cheap: no orbit)."""
    import linearize.analysis as la

    def fake_analyze(*a, **k):
        warnings.warn("a user-visible note from the model", UserWarning)
        raise RuntimeError("stand-in stops here")

    monkeypatch.setattr(la, "analyze", fake_analyze)
    with pytest.warns(UserWarning, match="a user-visible note from the model"):
        assert cli_main(["study", "--model", DOUBLE, "--quick", "--out", str(tmp_path)]) == 1
    assert json.loads((tmp_path / "study.json").read_text())["stages"]["floquet"]["status"] == "failed"


def test_failed_tuning_validates_at_zero_gains_and_says_so(tmp_path, monkeypatch):
    """When the tuning stage fails there are no tuned gains: the validation runs at zero gains and the section
    and study.json say "tuning failed: validated at zero gains" (it used to say "no drives (uncontrolled)" for
    a model that has two).  The tuning is made to fail by a stand-in plant rule that raises; the charts are
    stubbed out and the nonlinear measurement is a stand-in recording the gains it is asked for (cheap)."""
    import flexstab.chart_runs as chart
    import flexstab.plants as plants
    import flexstab.study as fs
    import validation.multipliers as vm
    import validation.plots as vp
    from flexstab.model_study import TUNING_FAILED_VALIDATION

    def fails(*a, **k):
        raise ArithmeticError("no main-mode multiplier confirmed")

    asked: list = []
    headers: list = []

    class Confirmed:
        def to_dict(self):
            return {"agrees": True}

    def measure(definition, omega, kp, kd, **k):
        asked.append((kp, kd))
        return Confirmed()

    monkeypatch.setattr(plants, "plant_choice_for", fails)
    monkeypatch.setattr(chart, "model_charts", fails)
    monkeypatch.setattr(vm, "validate_model_multipliers", measure)
    monkeypatch.setattr(vp, "plot_multiplier_plane", lambda *a, **k: None)
    monkeypatch.setattr(fs, "validation_blocks", lambda d, header, *a: headers.append(header) or [])
    out = tmp_path / "o"
    assert cli_main(["study", "--model", DOUBLE, "--quick", "--out", str(out)]) == 1
    stages = json.loads((out / "study.json").read_text())["stages"]
    assert stages["tuning"]["status"] == "failed" and "no main-mode multiplier" in stages["tuning"]["error"]
    assert asked == [(0.0, 0.0)]  # validated at zero gains ...
    v = stages["validation"]
    assert v["status"] == "computed" and v["note"] == TUNING_FAILED_VALIDATION  # ... and said so
    assert json.loads((out / "validation.json").read_text())["gains_source"] == TUNING_FAILED_VALIDATION
    assert TUNING_FAILED_VALIDATION in headers[0] and "no drives" not in headers[0]
    assert f"**Note:** {TUNING_FAILED_VALIDATION}" in (out / "report.md").read_text()


@pytest.mark.slow
def test_a_second_run_reuses_every_stage_and_a_changed_input_reruns_what_it_reaches(tmp_path):
    """Resuming (flexstab.stages): the same inputs again -> every stage "reused", a small fraction of the
    first run's CPU, every data file byte for byte the same; then a changed target (an input of the
    tuning, the charts and, through the gains, the validation, not of the orbit) -> the floquet stage
    reused, the others computed.  Rejects a model study that recomputes everything (it used to) and one
    that reuses a stage whose inputs changed."""
    from flexstab.stages import cpu_now

    out = tmp_path / "o"

    def run(*extra):
        c0 = cpu_now()
        rc = cli_main(["study", "--model", DOUBLE, "--quick", "--out", str(out), *extra])
        return rc, cpu_now() - c0, json.loads((out / "study.json").read_text())["stages"]

    rc, cpu1, first = run()
    assert rc == 0 and {v["status"] for v in first.values()} == {"computed"}
    data = {f: (out / f).read_bytes() for f in ("floquet.json", "tuning.json", "charts.json", "validation.json",
                                               "multipliers.csv")}
    rc, cpu2, again = run()
    assert rc == 0 and {k: v["status"] for k, v in again.items()} == dict.fromkeys(first, "reused")
    assert cpu2 < 0.1 * cpu1, (cpu1, cpu2)
    assert all((out / f).read_bytes() == b for f, b in data.items())
    report = (out / "report.md").read_text()
    assert report.count("reused from the run finished at") == 4
    assert json.loads((out / "manifest.json").read_text())["status"] == "finished"
    cfg = tmp_path / "c.toml"
    cfg.write_text("[study]\ntarget = 0.35\n")
    rc, _, changed = run("--config", str(cfg))
    assert rc == 0
    assert {k: v["status"] for k, v in changed.items()} == {"floquet": "reused", "tuning": "computed",
                                                           "charts": "computed", "validation": "computed"}
    assert json.loads((out / "tuning.json").read_text())["target"] == 0.35
    assert json.loads((out / "tuning.stage.json").read_text())["inputs"]["target"] == 0.35


def test_interrupted_model_study_says_so_in_its_manifest(tmp_path, monkeypatch, capsys):
    """Ctrl-C inside a stage: exit 130, ``manifest.json`` "interrupted", the folder's lock released (the model
    study runs on the paper study's stage runner; it had no manifest).  A stand-in ``analyze`` is interrupted."""
    import linearize.analysis as la
    from flexstab.stages import LOCK_FILE

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(la, "analyze", interrupted)
    assert cli_main(["study", "--model", DOUBLE, "--quick", "--out", str(tmp_path)]) == 130
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and manifest["stages"] == {}
    assert not (tmp_path / LOCK_FILE).exists() and not (tmp_path / "report.md").exists()
