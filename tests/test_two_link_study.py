"""Pieces of the two-link study (flexstab.two_link) that need no orbit."""
from __future__ import annotations

import pytest

from flexstab.two_link import dominant_damped, main_dominant
from linearize.analysis import ModeLabel


def _m(mode, undamped=False):
    return ModeLabel(modulus=0.5, mode=mode, drive_shares={}, group="", frequency_hz=1.0, mac=1.0, shares={},
                     undamped=undamped)


def test_main_dominant_prefers_drive_and_first_bending_modes():
    mus = [0.66 + 0.1j, 0.66 - 0.1j, 0.30, 0.2, 1.0]
    modes = [_m("axial 9"), _m("axial 9"), _m("elbow"), _m("bending 1"), _m("axial 2", True)]
    # the axial artefact is larger but is not one of the modes a rigid / one-mode model has
    assert main_dominant(mus, modes, ("shoulder", "elbow")) == pytest.approx(0.30)
    # without drive / bending-1 modes: the largest off the unit circle
    assert main_dominant(mus[:2] + [1.0], modes[:2] + [_m("axial 2", True)], ("shoulder",)) == pytest.approx(0.66 + 0.1j)
    # an undamped drive mode does not count
    assert main_dominant([1.0005, 0.4], [_m("elbow", True), _m("shoulder")], ("shoulder", "elbow")) == pytest.approx(0.4)


def test_dominant_damped_skips_the_unit_circle():
    assert dominant_damped([1.0009, -0.9995, 0.71, 0.2]) == pytest.approx(0.71)
    assert dominant_damped([1.0, 0.9999]) == pytest.approx(1.0)  # nothing off the circle: the largest


@pytest.mark.slow
def test_study_section_tunes_its_gains_and_they_reach_target_by_an_independent_method(tmp_path):
    """The study's two-link stage computes everything it shows: it tunes the four gains itself (no script to
    run first, no stored gains; a stray script result in the folder is not read) and the tuned gains give
    |rho| within 1e-3 rho_d of rho_d = 0.3 by Hill (the loop's method) AND by an independent method
    recomputed here: the exponential midpoint in frozen-modal coordinates (stability.modal),
    Richardson-extrapolated from 512 / 256 steps, whose own estimate (~2e-5) is far below the band (3e-4).
    All gains 30 % lower leave the band (the check can fail)."""
    import json
    import math

    import numpy as np

    from flexstab.config import StudyConfig
    from flexstab.study import StudyOptions, run_study
    from flexstab.two_link import TUNED_GAINS
    from stability.modal import modal_floquet

    stray = tmp_path / "two_link" / "two_link.json"  # a script result of other gains: must not be read
    stray.parent.mkdir()
    stray.write_text(json.dumps({"target": 0.3, "tune": {"2pi": {"gains": [0.7 * v for v in TUNED_GAINS[2]]}}}))
    res = run_study(StudyConfig(), StudyOptions(out=tmp_path, quick=True, stages=("two_link",), progress=False,
                                                jobs=1))
    assert res.stages["two_link"]["status"] == "computed"
    doc = json.loads((tmp_path / "two_link.json").read_text())
    md = (tmp_path / "report.md").read_text()
    assert "Two-link flexible arm" in md and "issue" not in md.lower()
    assert "run `python3 scripts" not in md and "TUNED_GAINS" not in md and "No usable results" not in md
    row = doc["rows"][0]
    assert row["tuning"]["status"] == "converged" and row["check"]["confirmed"] is True
    g = row["tuned_gains"]
    assert g == row["tuning"]["gains"]
    # the mode figure states the modulus the table states (Hill's), with the method and the drawn scale
    fig = row["tuned"]["mode_figure"]
    assert fig["modulus"] == row["tuned"]["dominant_modulus"] and fig["method"].startswith("Hill's method")
    assert 0 < fig["deformation_scale_m"] < 0.2
    hill = row["tuned"]["dominant_modulus"]
    assert row["tuned"]["mode"] in ("shoulder", "elbow")
    band = 1e-3 * 0.3

    from flexstab.two_link import two_link_orbit
    from linearize.constrained import linearize_orbit

    o = two_link_orbit(2 * math.pi)
    lin = linearize_orbit(o, 0.0, 0.0)

    def modal(gains):
        r = modal_floquet(lin.with_gains(gains[0::2], gains[1::2]), method="magnus2", n_steps=512, extrapolate=True)
        w = np.asarray(r.multipliers)
        return abs(w[int(np.argmin(np.abs(w - hill)))]), float(r.error_estimate)

    m, est = modal(g)
    assert est < 0.1 * band
    assert abs(hill - 0.3) <= band and abs(m - 0.3) <= band + est, (hill, m, est)
    assert abs(m - hill) <= est + 1e-6
    assert abs(row["check"]["modulus"] - m) <= 1e-12  # the stage's check is this computation
    off, _ = modal(tuple(0.7 * v for v in g))
    assert abs(off - 0.3) > band


def test_stale_cache_parts_are_ignored_with_a_note(tmp_path):
    """The script's merge keeps each stage's keys; the study uses a part only if its keys equal its own
    (code hash, mesh, ranges, rho_d) and names what differs otherwise.  Rejects a cache read whatever
    code or inputs produced it.  No orbit: the merge and the key rule only."""
    import importlib.util
    import json
    from pathlib import Path

    from flexstab.two_link_report import cache_keys, fresh_parts

    spec = importlib.util.spec_from_file_location(
        "two_link_study_script", Path(__file__).resolve().parents[1] / "scripts" / "two_link_study.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    keys = cache_keys(0.3)
    (tmp_path / "two_link_tune.json").write_text(json.dumps({"target": 0.3, "tune": {"2pi": {}}, "keys": keys}))
    (tmp_path / "two_link_mesh.json").write_text(json.dumps({"mesh": {"2pi": []}, "keys": dict(keys, target=0.5)}))
    (tmp_path / "two_link_robust.json").write_text(json.dumps({"robust": {"2pi": {}}}))  # an older script: no keys
    doc = script.merge(tmp_path)
    assert json.loads((tmp_path / "two_link.json").read_text()) == doc
    fresh, notes = fresh_parts(doc, keys)
    assert set(fresh) == {"tune", "target"}
    assert notes == ["`mesh` ignored: computed with other target",
                     "`robust` ignored: computed without keys (an older script)"]
    assert fresh_parts(doc, dict(keys, code="other"))[0] == {}  # a code change invalidates every part
    # the script starts a stage file again when its keys are not the current ones
    assert script._resume(tmp_path / "two_link_mesh.json", keys, {"mesh": {}}) == {"mesh": {}, "keys": keys}
    assert script._resume(tmp_path / "two_link_tune.json", keys, {})["tune"] == {"2pi": {}}


def test_mode_title_shows_the_measured_modulus_and_its_method():
    """The two-link figure at 4 pi showed the 512-step product's 0.3023 while the table showed Hill's 0.300027:
    with ``measured`` the title carries the table's value (6 digits, as the table) and the method."""
    from types import SimpleNamespace

    from flexstab.arm_figures import mode_title

    orbit = SimpleNamespace(model=SimpleNamespace(name="two-link"), omega=4 * 3.141592653589793)
    t = mode_title(orbit, 0.3023 + 0.0j, "elbow", (0.300027 + 0.0j, "Hill's method, 16 harmonics"))
    assert "|ρ| = 0.300027 (elbow; Hill's method, 16 harmonics)" in t and "0.3023" not in t
    assert "|ρ| = 0.3023 (elbow)" in mode_title(orbit, 0.3023 + 0.0j, "elbow")


def test_cache_keys_cover_the_stage_arguments_and_the_script(tmp_path):
    """The keys were the package hash, mesh, ranges and rho_d only, so the robust stage resumed a
    file whose other Omegas' rows used another ``--grid`` / ``--robust-iterations``, and a change of the
    script's own constants (MESH, the direct stage's 2 elements; ``scripts/`` is not a hashed package) kept
    old parts in use.  Now each stage's keys carry its arguments and the script's SHA-256."""
    import argparse
    import hashlib
    import importlib.util
    import json
    from pathlib import Path

    from flexstab.two_link_report import cache_keys, fresh_parts

    path = Path(__file__).resolve().parents[1] / "scripts" / "two_link_study.py"
    spec = importlib.util.spec_from_file_location("two_link_study_script", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    base = cache_keys(0.3)
    assert base["script"] == hashlib.sha256(path.read_bytes()).hexdigest()  # the file itself, hashed here

    def args(**kw):
        d = dict(workers=2, compare=False, direct_from=None, grid=4, robust_iterations=4, robust_workers=1)
        return argparse.Namespace(**dict(d, **kw))

    k4 = script.stage_keys(0.3, "robust", args())
    k7 = script.stage_keys(0.3, "robust", args(grid=7))
    assert k4["args"] == {"grid": 4, "robust_iterations": 4, "robust_workers": 1} and k4 != k7
    assert script.stage_keys(0.3, "robust", args(robust_iterations=2)) != k4
    assert script.stage_keys(0.3, "robust", args(workers=1)) == k4  # the tune stage's argument: not the robust's
    # the robust stage computed with grid 4 at 2 pi is started again by a grid-7 run (was: resumed, rows mixed)
    p = tmp_path / "two_link_robust.json"
    p.write_text(json.dumps({"robust": {"2pi": {"grid_size": 64}}, "keys": k4}))
    assert script._resume(p, k7, {"robust": {}}) == {"robust": {}, "keys": k7}
    assert script._resume(p, k4, {"robust": {}})["robust"] == {"2pi": {"grid_size": 64}}
    # the study uses a part whatever the script run's own arguments, but not one of another script version
    doc = {"robust": {"2pi": {}}, "mesh": {"2pi": []},
           "keys": {"robust": k4, "mesh": dict(script.stage_keys(0.3, "mesh", args()), script="0" * 64)}}
    fresh, notes = fresh_parts(doc, base)
    assert set(fresh) == {"robust"} and notes == ["`mesh` ignored: computed with other script"]
