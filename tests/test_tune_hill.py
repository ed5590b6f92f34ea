"""``flexstab tune --model two-link``: the Hill path and ``--robust`` end to end, 1 element per link.

Oracles: the independent re-check that ``tune`` itself runs at the tuned gains (the streamed
exponential-midpoint product, no Hill code) and, for ``--robust``, the frozen-modal magnus2 product
(:mod:`stability.modal`) on an orbit built here at the reported worst noise.  Kept cheap: one L9
experiment (``--max-evaluations 10``), the re-check at 4096/8192 steps instead of 16384/32768.
"""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from flexstab.cli import main as cli_main


def _run(capsys, argv):
    rc = cli_main(argv)
    out, err = capsys.readouterr()
    return rc, json.loads(out), err


@pytest.mark.slow
def test_tune_two_link_hill_path(monkeypatch, capsys):
    """One L9 experiment with Hill's response; the harmonics cannot meet an impossible tolerance (1e-14 / 20,
    below Hill's round-off), which must warn and show as ``harmonics_converged: false`` in the JSON."""
    import flexstab.plants as plants
    import flexstab.two_link as two_link

    monkeypatch.setattr(two_link, "CHECK_STEPS", (4096, 8192))
    monkeypatch.setattr(plants, "HILL_HARMONICS", (8,))
    with pytest.warns(RuntimeWarning, match="none of"):
        rc, d, err = _run(capsys, ["tune", "--model", "two-link", "--elements", "1", "--max-evaluations", "10",
                                   "--workers", "1", "--tolerance", "1e-14", "--json"])
    # one line (besides the progress lines of a slow run, flexstab.progress): 10 evaluations cannot reach 1e-14
    lines = [ln for ln in err.splitlines() if not re.match(r"^[^:]+: \d+/\d+ \w+ \(\d+ %\), ", ln)]
    assert rc == 1 and len(lines) == 1 and "not converged" in err
    assert d["response_method"] == "hill" and d["harmonics"] == 8 and d["elements"] == 1
    assert d["harmonics_converged"] is False and d["harmonics_error_estimate"] > 1e-14 / 20
    assert d["evaluations"] == 10 and len(d["iterations"]) == 1 and d["failed_runs"] == []
    # every run's response met its budget with Hill's own value (no frozen-modal fallback at these gains)
    assert d["fallback_runs"] == []
    assert d["verified_method"] == "magnus2, 8192 steps (streamed)"
    for key in ("spectral_radius_all", "spectral_radius_all_mode", "verified_error_estimate", "hill_error_estimate"):
        assert d[key] is not None, key
    # the tuned response (Hill) against the streamed product at the same gains: within the product's
    # step-doubling bound (4/3 |r_2n - r_n|, second order) plus Hill's H vs H/2 estimate (relative)
    tol = d["verified_error_estimate"] + d["hill_error_estimate"] * d["tuned_response"]
    assert abs(d["tuned_response"] - d["verified_spectral_radius"]) <= tol
    # ... a tolerance that singles out the tuned run among the experiment's runs (another value would fail)
    it = d["iterations"][0]
    ys = it["responses"] + [it["confirmation"]["spectral_radius"]]
    assert sum(abs(y - d["verified_spectral_radius"]) <= tol for y in ys) == ys.count(d["tuned_response"])


class _Falling:
    """A plant stub whose every run is a 'fallback' (records like HillModelPlant.spectral_measure)."""

    drives = ("a",)

    def __init__(self) -> None:
        self.fallback_runs: list = []

    def spectral_measure(self, kp, kd) -> float:  # one drive: floats (stability.gains.Gains.arguments)
        self.fallback_runs.append({"gains": [kp, kd], "method": "modal-magnus2"})
        return kp + kd


@pytest.mark.parametrize("pool", [False, True])
def test_fallback_records_come_back_from_workers(pool):
    """A run's fallback record is made in the worker's copy of the plant; tune's executor wrapper
    returns it with the value (once each, also in-process), and the values are unchanged."""
    import concurrent.futures as cf
    import multiprocessing

    from flexstab.tuning import FallbackRecorder
    from taguchi.tuning import GainObjective

    plant = _Falling()
    inner = (cf.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork")) if pool
             else cf.ThreadPoolExecutor(1))
    with inner:
        ex = FallbackRecorder(inner, plant)
        ys = list(ex.map(GainObjective(plant), [(1.0, 2.0), (3.0, 4.0)]))
    assert ys == [3.0, 7.0]
    assert [r["gains"] for r in ex.records] == [[1.0, 2.0], [3.0, 4.0]] and plant.fallback_runs == []


@pytest.mark.slow  # ~17 s CPU: 9 orbits + 66 Hill evaluations is the smallest design the options allow
def test_tune_robust_two_link_tiny(tmp_path, capsys):
    """``tune --robust --model two-link`` end to end on the smallest design the options allow (inner L9 x outer
    L4, one crossed experiment, a 2^3 noise grid, 1 element): the documented JSON fields are present and
    consistent, and the nominal gains' worst grid value matches the frozen-modal product on an orbit built here."""
    from linearize.constrained import linearize_orbit
    from linearize.hill_plant import HillModelPlant
    from mbs_models.builtin.two_link import TwoLinkParameters
    from flexstab.two_link import two_link_orbit
    from stability.hill import TAIL_LIMIT
    from stability.modal import modal_floquet

    cfg = tmp_path / "tiny.toml"
    cfg.write_text("[robust]\nlevels = 2\ngrid = 2\nmax_iterations = 1\n")
    rc, d, _ = _run(capsys, ["tune", "--model", "two-link", "--robust", "--elements", "1", "--max-evaluations", "10",
                             "--workers", "1", "--config", str(cfg), "--json"])
    assert rc == (0 if d["converged"] else 1)
    nom, rob = d["nominal"], d["robust"]
    assert d["model"] == "two-link" and d["robust_design"] is True and d["target"] == 0.3
    assert rob["inner_array"].startswith("L9") and rob["outer_array"].startswith("L4") and rob["sn_kind"] == "target"
    assert [n["name"] for n in rob["noise"]] == ["tip_mass", "omega_scale", "youngs_modulus_scale"]
    assert d["grid_size"] == 8 and rob["check"]["grid_size"] == 8 and len(rob["iterations"]) == 1
    for row in (nom, rob["check"]):
        assert len(row["gains"]) == 4 and row["min"] <= row["mean"] <= row["worst"]
        assert set(row["worst_noise"]) == {"tip_mass", "omega_scale", "youngs_modulus_scale"}
    assert d["worst_case_improvement"] == pytest.approx(nom["worst"] - rob["check"]["worst"], abs=1e-15)
    # independent value: the nominal gains at their worst noise, frozen-modal magnus2 (extrapolated, bound
    # 4/3 |r_256 - r_128|) on an orbit built here; Hill's value was not flagged truncated, so its relative
    # error is below sqrt(TAIL_LIMIT) (stability.hill.TAIL_LIMIT's derivation)
    wn = nom["worst_noise"]
    orbit = two_link_orbit(d["omega"] * wn["omega_scale"], 1, tip_mass=wn["tip_mass"],
                           youngs_modulus=TwoLinkParameters.youngs_modulus * wn["youngs_modulus_scale"])
    lin = linearize_orbit(orbit, 0.0, 0.0)
    g = nom["gains"]
    hill = HillModelPlant(lin, orbit, harmonics=12).measure(g[0::2], g[1::2])
    lg = lin.with_gains(g[0::2], g[1::2])
    ref = []
    for n in (128, 256):
        w = np.asarray(modal_floquet(lg, method="magnus2", n_steps=n, extrapolate=True).multipliers)
        ref.append(abs(w[int(np.argmin(np.abs(w - hill.dominant)))]))
    tol = 4.0 / 3.0 * abs(ref[1] - ref[0]) + math.sqrt(TAIL_LIMIT) * ref[1]
    assert abs(nom["worst"] - ref[1]) <= tol, (nom["worst"], ref, tol)
    # the grid's other values are farther than that (the check tells the worst noise from the rest)
    assert nom["worst"] - nom["min"] > tol
