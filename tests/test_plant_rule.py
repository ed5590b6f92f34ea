"""``tune --model``, ``study --model`` and ``chart --model`` evaluate one response by one method.

:func:`flexstab.plants.plant_for` is the one rule (Hill's method for the built-in two-link, the
frozen-modal product with its steps chosen at the range centre otherwise).  With the same ranges,
target and tolerance the three commands build the same plant, so the first L9 experiment of
``tune`` and of ``study`` picks the same gains, and the chart's value at those gains is the same
number: the same deterministic computation on the same orbit, so they agree to rounding
(``REL = 1e-12``: a few hundred ulps of an eigenvalue solve repeated on bit-identical inputs).
The wrong answer this rejects: the chart and the study on ``ModelPlant`` (magnus2) while ``tune`` uses
Hill -- on the 1-element two-link they differ by ~6e-7 (checked below, so the comparison can fail).
Cheap: 1 element per link, one L9 experiment (10 evaluations), the costly after-checks of ``tune``
(streamed 32768-step product, whole spectrum) and the study's charts / nonlinear validation stubbed.
"""
from __future__ import annotations

import json
import math

import pytest

from flexstab.cli import main as cli_main

@pytest.fixture
def stub_model_file(tmp_path, monkeypatch):
    """A file ``x.py`` in the working folder: the CLI checks that a model file exists before it imports
    anything; the tests stub what would be built from it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.py").write_text("def build(mbs, omega):\n    return []\n")


REL = 1e-12
RANGES = ["--kp-range", "0", "30", "--kd-range", "0", "10"]


def _stub_tune_after_checks(monkeypatch):
    import flexstab.plants as plants
    import flexstab.two_link as tl

    class Check:
        streamed = {32768: 0.0}
        magnus_error_estimate = 0.0
        hill_error_estimate = 0.0

    monkeypatch.setattr(plants, "whole_spectrum", lambda *a, **k: {})
    monkeypatch.setattr(plants, "mesh_dependence", lambda *a, **k: [])
    monkeypatch.setattr(tl, "check_multiplier", lambda *a, **k: Check())


def _stub_study_tail(monkeypatch):
    import flexstab.chart_runs as chart
    import validation.multipliers as vm

    def stub(*a, **k):
        raise RuntimeError("stubbed out in this test")

    monkeypatch.setattr(chart, "model_charts", stub)
    monkeypatch.setattr(vm, "validate_model_multipliers", stub)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["two-link", "single-link"])
def test_tune_study_and_chart_give_the_same_response(model, tmp_path, monkeypatch, capsys):
    import flexstab.model_study as ms

    _stub_tune_after_checks(monkeypatch)
    assert cli_main(["tune", "--model", model, "--elements", "1", *RANGES, "--max-evaluations", "10",
                     "--workers", "1", "--json"]) == 1  # one experiment: not converged (exit 1), gains chosen
    t = json.loads(capsys.readouterr().out)
    assert t.get("response_method") == ("hill" if model == "two-link" else None)

    cfg = tmp_path / "c.toml"
    cfg.write_text("[study]\nkp_range = [0.0, 30.0]\nkd_range = [0.0, 10.0]\nelements = 1\n")
    out = tmp_path / "study"
    with monkeypatch.context() as m:
        _stub_study_tail(m)
        m.setattr(ms, "QUICK_EVALUATIONS", 10)
        cli_main(["study", "--model", model, "--elements", "1", "--quick", "--config", str(cfg), "--out", str(out)])
    capsys.readouterr()
    s = json.loads((out / "tuning.json").read_text())
    assert s["response_method"] == ("hill" if model == "two-link" else "magnus2")
    assert s["tuning"]["gains"] == t["gains"]  # the same plant ranks the L9 runs alike
    assert s["tuning"]["spectral_radius"] == pytest.approx(t["tuned_response"], rel=REL, abs=0)

    kp = ",".join(repr(v) for v in t["gains"][0::2])
    kd = ",".join(repr(v) for v in t["gains"][1::2])
    w = 2 * math.pi
    assert cli_main(["chart", "--model", model, "--elements", "1", *RANGES, "--kp", kp, "--kd", kd, "--no-taguchi",
                     "--grid", "2", "--omega-range", repr(w), repr(1.1 * w), "--omega-points", "2",
                     "--out", str(tmp_path / "chart"), "--json"]) == 0
    c = json.loads(capsys.readouterr().out)
    assert c["response_method"] == s["response_method"]
    assert c["omega_chart"]["omega"][0] == w
    assert c["omega_chart"]["spectral_radius_controlled"][0] == pytest.approx(t["tuned_response"], rel=REL, abs=0)
    # the discretisation choice is recorded alike: the step choice at the range centre for a
    # time-stepping plant; for Hill the chart's stable propagator_* fields hold the labelling steps and the
    # absolute H vs H/2 estimate, beside tune's names (label_steps, relative hill_error_estimate)
    if model == "two-link":
        assert "propagator_choice" not in t and s["propagator_choice"] is None and c["propagator_choice"] is None
        assert c["propagator_steps"] == c["label_steps"] == t["propagator_steps"]
        rho = c["omega_chart"]["spectral_radius_controlled"][0]
        assert c["propagator_error_estimate"] == pytest.approx(c["hill_error_estimate"] * rho, rel=1e-12)
    else:
        assert t["propagator_choice"] == s["propagator_choice"] == c["propagator_choice"]
        assert c["propagator_choice"]["n_steps"] == c["propagator_steps"] and c["propagator_choice"]["converged"]
        assert c["label_steps"] is None and c["hill_error_estimate"] is None

    if model == "two-link":  # the comparison can fail: the time-stepping plant is another number
        from flexstab.two_link import two_link_orbit
        from linearize.analysis import ModelPlant
        from linearize.constrained import linearize_orbit

        o = two_link_orbit(w, 1)
        other = ModelPlant(linearize_orbit(o), o).spectral_measure(t["gains"][0::2], t["gains"][1::2])
        assert abs(other - t["tuned_response"]) > 1e3 * REL * t["tuned_response"]


def test_hill_plant_caches_are_lru_functions_shared_by_copies_and_pickles():
    """The labelling workspace and the frozen modes are cached per process by ``functools.lru_cache`` on the
    plant's token (no module-level dict): a pickled copy (what a process pool unpickles per task)
    and a ``replace`` copy reuse them -- cache hits, no new build -- while another plant of the same arm builds
    its own.  Rejects a cache that pickled copies miss (a workspace rebuilt per task) or that two plants share."""
    import pickle

    import linearize.hill_plant as hp
    from flexstab.two_link import two_link_orbit
    from linearize.constrained import linearize_orbit

    assert not [k for k, v in vars(hp).items() if isinstance(v, dict) and not k.startswith("__")]
    o = two_link_orbit(2 * math.pi, 1)
    lin = linearize_orbit(o)
    plant = hp.HillModelPlant(lin, o, harmonics=8)
    kp, kd = [15.0, 7.0], [9.0, 1.5]
    r = plant.spectral_measure(kp, kd)
    ws0, fm0 = hp._labelling_workspace.cache_info(), hp._frozen_modes.cache_info()
    for copy in (pickle.loads(pickle.dumps(plant)), plant.replace(harmonics=8)):
        assert copy.spectral_measure(kp, kd) == r
    ws1, fm1 = hp._labelling_workspace.cache_info(), hp._frozen_modes.cache_info()
    assert ws1.misses == ws0.misses and ws1.hits > ws0.hits and fm1.misses == fm0.misses and fm1.hits > fm0.hits
    hp.HillModelPlant(lin, o, harmonics=8).spectral_measure(kp, kd)  # a new plant: a new token, its own entries
    # (the labelling pass and its half-step pass, which the far-landing match compares with)
    assert hp._labelling_workspace.cache_info().misses == ws1.misses + 2


def test_chart_plants_are_an_explicit_cache_shared_by_the_tasks(tmp_path):
    """``ModelRadius`` is frozen and holds no cache of its own: the orbits live in the ``ModelPlants`` object
    passed in, shared by the copies of the task (one orbit per Omega), and the plant is ``plant_for``'s."""
    import dataclasses

    from flexstab.charts import ModelPlants, ModelRadius
    from linearize.analysis import ModelPlant
    from test_constrained_linearisation import DOUBLE

    assert all(f.type not in ("dict", dict) for f in dataclasses.fields(ModelRadius))
    plants = ModelPlants(DOUBLE, samples=16)
    a = ModelRadius(plants, steps=32)
    b = dataclasses.replace(a, drive=1, fixed_kp=(5.0, 0.0), fixed_kd=(0.5, 0.0))
    pa, pb = a.plant(6.0), b.plant(6.0)
    assert pa is pb and isinstance(pa, ModelPlant) and pa.n_steps == 32
    assert list(plants._linearised) == [6.0]
    assert b({"omega": 6.0, "kp": 1.0, "kd": 0.2}) == pa.spectral_measure([5.0, 1.0], [0.5, 0.2])


@pytest.mark.parametrize("tty", [True, False])
def test_progress_rule_is_the_same_for_tune_chart_and_study_model(stub_model_file, tty, tmp_path, monkeypatch, capsys):
    """tqdm bars on a terminal stderr, none otherwise, for all three commands (``study --model`` once had it
    inverted: bars off on a terminal); on a non-terminal the study prints one line per stage event instead.
    The commands' work is stubbed: only the flag each passes on is recorded."""
    import sys
    from types import SimpleNamespace

    import flexstab.chart_runs as chart
    import flexstab.model_study as ms
    import flexstab.plants as plants
    import flexstab.tuning as tune

    seen: dict = {}
    monkeypatch.setattr(sys.stderr, "isatty", lambda: tty)

    def fake_charts(opts, cfg, progress=True):
        seen["chart"] = progress
        return {"gain_chart": None, "figures": []}

    def fake_tune(plant, tcfg, *, executor=None, progress=False):
        seen["tune"] = progress
        raise RuntimeError("stop here")

    def fake_study(model, cfg, opts):
        seen["study"] = (opts.progress, opts.log is None)
        return SimpleNamespace(stages={}, report_md="r.md", report_html="r.html", elapsed=0.0)

    from flexstab.plants import PlantChoice

    base = SimpleNamespace(drives=("a",), orbit=SimpleNamespace(model=None), linearization=None,
                           spectral_measure=lambda kp, kd: 0.3)
    monkeypatch.setattr(chart, "make_charts", fake_charts)
    monkeypatch.setattr(tune, "build_plant", lambda *a, **k: base)
    monkeypatch.setattr(plants, "plant_choice_for", lambda *a, **k: PlantChoice(base))
    monkeypatch.setattr(tune, "tune_model_plant", fake_tune)
    monkeypatch.setattr(ms, "run_model_study", fake_study)
    assert cli_main(["chart", "--model", "x.py", "--out", str(tmp_path)]) == 0
    assert cli_main(["tune", "--model", "x.py"]) == 1
    assert cli_main(["study", "--model", "x.py", "--out", str(tmp_path)]) == 0
    # the progress rule (flexstab.progress.progress_bars): tqdm bars on a terminal, one line per step otherwise
    from flexstab.progress import LineProgress

    assert set(seen) == {"chart", "tune", "study"}
    for name in ("chart", "tune"):
        assert (seen[name].func is not LineProgress) == tty, name
    assert (seen["study"][0].func is not LineProgress) == tty and seen["study"][1] == tty
