"""``flexstab tune --model PATH.py`` with two drives: four gains (kp1, kd1, kp2, kd2) tuned by Taguchi (L9),
the reached multiplier checked against the hand-derived linearisation of the double pendulum integrated
by scipy (independent of the package), and one-line errors for bad ranges."""
from __future__ import annotations

import contextlib
import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate

from flexstab.cli import main as cli_main
from test_constrained_linearisation import double_pendulum_matrices  # hand-derived, written without the package

@pytest.fixture
def stub_model_file(tmp_path, monkeypatch):
    """A file ``fake.py`` in the working folder: the CLI checks that a model file exists before it imports
    anything; the tests stub what would be built from it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "fake.py").write_text("def build(mbs, omega):\n    return []\n")


HERE = Path(__file__).parent
DOUBLE = str(HERE / "models" / "double_pendulum.py")
OMEGA = 2 * math.pi
TARGET = 0.5
# the tuning stops at |r_loop - rho_d| <= TUNING_TOL; see test_four_gains_reach_target for the budget
TUNING_TOL = 5e-4 * TARGET
ARGS = ["tune", "--model", DOUBLE, "--omega", "2pi", "--target", str(TARGET),
        "--kp-range", "0", "20", "--kd-range", "0", "5"]


def reference_spectral_radius(kp, kd) -> float:
    """max|rho| of the hand-derived linearisation: the monodromy matrix by DOP853 (rtol 1e-10), all four
    columns in one integration."""
    T = 2 * math.pi / OMEGA

    def rhs(t, x):
        M, C, K = double_pendulum_matrices(t, OMEGA, kp, kd)
        X = x.reshape(4, 4)
        A = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
        return (A @ X).ravel()

    sol = scipy.integrate.solve_ivp(rhs, (0.0, T), np.eye(4).ravel(), method="DOP853", rtol=1e-10, atol=1e-12)
    return float(np.max(np.abs(np.linalg.eigvals(sol.y[:, -1].reshape(4, 4)))))


@pytest.fixture(scope="module")
def tuned():
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cli_main(ARGS + ["--tolerance", repr(TUNING_TOL), "--json"])
    return rc, json.loads(buf.getvalue())


def test_four_gains_reach_target(tuned):
    rc, d = tuned
    assert rc == 0 and d["converged"]
    assert d["drives"] == ["shoulder", "elbow"]
    assert d["names"] == ["kp1", "kd1", "kp2", "kd2"] and len(d["gains"]) == 4
    assert d["array"].startswith("L9")
    assert d["kp"] == d["gains"][0::2] and d["kd"] == d["gains"][1::2]
    assert d["evaluations"] >= 10 and len(d["iterations"]) >= 1
    for lo_hi, g in zip((d["iterations"][0][f"{s}_range"] for s in d["names"]), d["gains"]):
        assert lo_hi[0] <= g <= lo_hi[1]
    ref = reference_spectral_radius(d["kp"], d["kd"])
    # |ref - rho_d| <= |r_loop - rho_d| (<= TUNING_TOL = 5e-4 rho_d, the stopping rule)
    #                 + |ref - r_loop| (magnus2, 256 steps, O(h^2): step doubling 256 -> 512 moves it by
    #                   3e-7, so ~5e-7; collocation at 32 samples < 1e-6 (test_constrained_linearisation);
    #                   DOP853 at rtol 1e-10 ~1e-9)  ->  < 1e-3 rho_d with a wide margin
    assert abs(ref - d["tuned_response"]) <= 1e-5
    assert abs(ref - TARGET) <= 1e-3 * TARGET
    # the check can fail: the tuned shoulder/elbow kd raised by 5 % misses rho_d by far more than 1e-3 rho_d
    wrong = reference_spectral_radius(d["kp"], [1.05 * v for v in d["kd"]])
    assert abs(wrong - TARGET) > 1e-2 * TARGET


def test_whole_spectrum_reported_beside_the_tuned_response(tuned):
    """The JSON names the tuned quantity and reports the spectral radius of the whole linearisation at the
    tuned gains; for the rigid double pendulum (no structural modes) both are the hand-derived
    linearisation's max|rho| (DOP853, rtol 1e-10): the frozen-modal product's error estimate plus the
    collocation error (< 1e-6, test_constrained_linearisation) bound the difference."""
    rc, d = tuned
    assert d["response"].startswith("dominant multiplier")
    ref = reference_spectral_radius(d["kp"], d["kd"])
    assert abs(d["spectral_radius_all"] - ref) <= d["spectral_radius_all_error_estimate"] * ref + 1e-6
    assert d["spectral_radius_all"] >= d["tuned_response"] - 1e-6
    assert d["spectral_radius_all_mode"]
    # the field named spectral_radius is the whole loop's, with its label and its own estimate
    assert d["spectral_radius"] == d["spectral_radius_all"] and d["spectral_radius_mode"] == d["spectral_radius_all_mode"]
    assert abs(d["spectral_radius"] - ref) <= d["spectral_radius_error_estimate"] * ref + 1e-6
    # the check can fail: the spectral radius at gains 5 % off is outside the same band
    assert abs(reference_spectral_radius(d["kp"], [1.05 * v for v in d["kd"]]) - d["spectral_radius_all"]) > \
        d["spectral_radius_all_error_estimate"] * ref + 1e-6


def test_text_output_lists_each_drive(capsys):
    rc = cli_main(ARGS + ["--max-evaluations", "10"])
    out = capsys.readouterr().out
    assert rc == 1  # 10 evaluations: one L9 experiment and its confirmation run, not converged
    assert re.search(r"^drive shoulder: kp1 = \S+ +kd1 = \S+$", out, re.M)
    assert re.search(r"^drive elbow: kp2 = \S+ +kd2 = \S+$", out, re.M)
    assert "10 Floquet evaluations" in out


@pytest.mark.parametrize("extra, message", [
    (["--kp-range", "5", "1"], "--kp-range is empty or inverted"),  # checked before any numerical import
    (["--range", "kd2=3,1"], "kd2 range is empty or inverted"),
    (["--range", "kp3=0,1"], "unknown factor 'kp3'; the factors are kp1, kd1, kp2, kd2"),
    (["--range", "kp1=0"], "--range expects NAME=LO,HI"),
])
def test_bad_range_one_line(capsys, extra, message):
    rc = cli_main(ARGS + extra)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and message in err, err


def test_range_on_single_drive_model(capsys):
    """One drive: the factors are kp, kd; a per-drive name is rejected before any computation."""
    assert cli_main(["tune", "--range", "kp1=0,10"]) == 2
    assert "unknown factor 'kp1'; the factors are kp, kd" in capsys.readouterr().err


def test_one_drive_model_file_keeps_kp_kd(tmp_path, capsys):
    """One drive (the rigid bar of test_model_file: no gravity, no damping): J_O phi'' + kd phi' + kp phi = 0
    has constant coefficients, so max|rho| = max|eig(expm(A T))| exactly."""
    import scipy.linalg

    from test_model_file import _bar

    path = _bar(tmp_path)
    rc = cli_main(["tune", "--model", str(path), "--omega", "2pi", "--target", "0.3", "--kp-range", "0", "20",
                   "--kd-range", "0", "5", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert rc == 0 and d["converged"] and d["drives"] == ["joint"] and d["names"] == ["kp", "kd"]
    # the JSON typing rule: one value per drive, a list also for one drive (as floquet --json)
    assert isinstance(d["kp"], list) and isinstance(d["kd"], list) and len(d["kp"]) == len(d["kd"]) == 1
    d["kp"], d["kd"] = d["kp"][0], d["kd"][0]

    def rho(kp, kd):
        J = 0.1 + 1.0 * 0.5**2  # inertia about the pivot (COM 0.5 m away)
        A = np.array([[0.0, 1.0], [-kp / J, -kd / J]])
        return float(np.max(np.abs(np.linalg.eigvals(scipy.linalg.expm(A * 2 * math.pi / OMEGA)))))

    # the tuning stops at 1e-3 rho_d; magnus2 on a constant-coefficient system is exact up to round-off
    # and the collocated orbit is exact (rigid, no gravity) up to its Newton tolerance: margin 1e-6
    assert abs(rho(d["kp"], d["kd"]) - 0.3) <= 1e-3 * 0.3 + 1e-6
    assert abs(rho(d["kp"], 1.05 * d["kd"]) - 0.3) > 1e-2 * 0.3  # the check can fail


def test_model_without_drives_one_line(capsys):
    assert cli_main(["tune", "--model", str(HERE / "models" / "vertical_pendulum.py"), "--omega", "80"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "has no drives" in err, err


def test_propagator_steps_doubles_until_the_error_fits_the_tolerance():
    """A second-order response r_n = r + c / n^2: the chosen n has (4/3)|r_n - r_2n| = c / n^2 <= tol / 4."""
    from dataclasses import dataclass

    from flexstab.plants import MAX_TUNING_STEPS, propagator_steps
    from taguchi.tuning import TuningConfig

    @dataclass(frozen=True)
    class Fake:
        c: float
        n_steps: int = 256

        def spectral_measure(self, kp, kd):
            assert len(kp) == len(kd) == 2
            return 0.3 + self.c / self.n_steps**2

    cfg = TuningConfig(target=0.3, ranges=((0, 1),) * 4)  # tolerance 3e-4
    for c, n in ((1.0, 256), (100.0, 2048)):  # c / n^2 <= 7.5e-5: 1 / 256^2 = 1.5e-5; 100 / 1024^2 = 9.5e-5 > 7.5e-5
        assert propagator_steps(Fake(c), cfg).n_steps == n
    with pytest.warns(RuntimeWarning, match="MAX_TUNING_STEPS"):
        assert propagator_steps(Fake(1e9), cfg).n_steps == MAX_TUNING_STEPS  # capped, never a hang


def test_propagator_choice_at_the_cap_warns_and_records_the_estimate_reached():
    """At MAX_TUNING_STEPS the doubling stopped silently and returned a count whose estimate never
    met tolerance / 4.  Second-order fake r_n = r + c / n^2: the last pair compared is (2048, 4096), whose
    4/3 |r_2048 - r_4096| = 4/3 * c * 3/4 / 2048^2 = c / 2048^2 exactly (the fake's own closed form)."""
    from dataclasses import dataclass

    from flexstab.plants import MAX_TUNING_STEPS, propagator_choice
    from taguchi.tuning import TuningConfig

    @dataclass(frozen=True)
    class Fake:
        c: float
        n_steps: int = 256

        def spectral_measure(self, kp, kd):
            return 0.3 + self.c / self.n_steps**2

    cfg = TuningConfig(target=0.3, ranges=((0, 1),) * 4)  # tolerance 3e-4
    with pytest.warns(RuntimeWarning, match=r"estimate 2\.38e-01 .* above tolerance / 4 = 7\.50e-05"):
        ch = propagator_choice(Fake(1e6), cfg)
    assert ch.n_steps == ch.plant.n_steps == MAX_TUNING_STEPS and not ch.converged
    assert ch.error_estimate == pytest.approx(1e6 / 2048**2, rel=1e-9) and ch.tolerance == pytest.approx(3e-4)
    ok = propagator_choice(Fake(1.0), cfg)  # met at the first pair: 4/3 |r_256 - r_512| = 1 / 256^2
    assert ok.converged and ok.n_steps == 256 and ok.error_estimate == pytest.approx(1 / 256**2, rel=1e-9)
    assert ok.to_dict() == {"n_steps": 256, "converged": True, "error_estimate": ok.error_estimate,
                            "tolerance": ok.tolerance}


def _use_plant(monkeypatch, tune, plant) -> None:
    """``tune --model fake.py`` tunes ``plant``: no orbit (build_plant stubbed) and no step choice at the range
    centre (plant_choice_for returns ``plant`` as it is)."""
    from types import SimpleNamespace

    base = SimpleNamespace(drives=plant.drives, orbit=SimpleNamespace(model=None), linearization=None)
    monkeypatch.setattr(tune, "build_plant", lambda *a, **k: base)
    import flexstab.plants as plants
    from flexstab.plants import PlantChoice

    monkeypatch.setattr(plants, "plant_choice_for", lambda definition, orbit, lin, cfg: PlantChoice(plant))


def test_tuning_repeated_with_more_steps_when_the_check_at_the_tuned_gains_fails(stub_model_file, monkeypatch, capsys):
    """A plant whose response carries a second-order propagator error c / n^2 (c = 30): 256 steps err by
    4.6e-4 > tol 3e-4, so the tuning is repeated with 512 (1.1e-4, estimate above tol / 4) and 1024 steps
    (2.9e-5); the final gains are within tol + 2.9e-5 of rho_d in the exact response (n -> infinity)."""
    from dataclasses import dataclass

    import flexstab.tuning as tune

    def exact(kp, kd):
        return 1.0 / (1.0 + 0.1 * (sum(kp) + sum(kd)))

    @dataclass(frozen=True)
    class Fake:
        n_steps: int = 256
        drives: tuple = ("a", "b")

        def spectral_measure(self, kp, kd):
            return exact(kp, kd) + 30.0 / self.n_steps**2

    _use_plant(monkeypatch, tune, Fake())  # no check at the range centre
    rc = cli_main(["tune", "--model", "fake.py", "--target", "0.3", "--kp-range", "0", "10", "--kd-range", "0", "10",
                   "--json"])
    d = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert [p["propagator_steps"] for p in d["propagator_passes"]] == [256, 512, 1024]
    assert d["propagator_steps"] == 1024
    assert d["evaluations"] == sum(p["evaluations"] for p in d["propagator_passes"])
    assert abs(exact(d["kp"], d["kd"]) - 0.3) <= d["tolerance"] + 30.0 / 1024**2


def _fake_tune(monkeypatch, capsys, shift):
    """Fake plant: exact response plus a second-order error c / n^2 that also *moves* the solution by
    ``shift(n)`` in the gain sum; returns the JSON of ``tune``."""
    from dataclasses import dataclass

    import flexstab.tuning as tune

    @dataclass(frozen=True)
    class Fake:
        n_steps: int = 256
        drives: tuple = ("a", "b")

        def spectral_measure(self, kp, kd):
            return 0.6 * math.exp(-0.1 * (sum(kp) + sum(kd) - shift(self.n_steps))) + 30.0 / self.n_steps**2

    _use_plant(monkeypatch, tune, Fake())
    rc = cli_main(["tune", "--model", "fake.py", "--target", "0.3", "--kp-range", "0", "10", "--kd-range", "0", "10",
                   "--json"])
    assert rc == 0
    return json.loads(capsys.readouterr().out)


def test_repeated_pass_starts_from_the_tuned_gains_with_narrowed_ranges(stub_model_file, monkeypatch, capsys):
    """After the step-doubling check fails, the next pass starts around the previous gains with ranges of
    RESTART_WIDTH x the initial width (not from the initial ranges) and needs no more evaluations than the
    first; the result still meets the tolerance in the exact response."""
    from flexstab.tuning import RESTART_WIDTH

    d = _fake_tune(monkeypatch, capsys, lambda n: 0.0)
    first = d["iterations"][0]
    for s in d["names"]:
        lo, hi = first[f"{s}_range"]
        assert hi - lo == pytest.approx(RESTART_WIDTH * 10.0)
    passes = d["propagator_passes"]
    assert len(passes) >= 2 and all(p["evaluations"] <= passes[0]["evaluations"] for p in passes[1:]), passes
    exact = 0.6 * math.exp(-0.1 * (sum(d["kp"]) + sum(d["kd"])))
    assert abs(exact - 0.3) <= d["tolerance"] + 30.0 / d["propagator_steps"] ** 2


def test_warm_restart_falls_back_to_the_initial_ranges_when_its_window_misses(stub_model_file, monkeypatch, capsys):
    """If the finer propagator moves the solution out of the narrowed window (here by 15 in the gain sum:
    the target needs a sum of 21.9 with more than 256 steps, the window around the first pass's gains
    (sum 6.9) reaches at most 6.9 + 4 x 1.25 = 11.9), that pass is repeated from the initial ranges."""
    d = _fake_tune(monkeypatch, capsys, lambda n: 0.0 if n <= 256 else 15.0)
    assert d["converged"]
    steps = [(p["propagator_steps"], p["converged"]) for p in d["propagator_passes"]]
    assert steps[:3] == [(256, True), (512, False), (512, True)], steps  # the missed window, then full ranges
    exact = 0.6 * math.exp(-0.1 * (sum(d["kp"]) + sum(d["kd"]) - 15.0))
    assert abs(exact - 0.3) <= d["tolerance"] + 30.0 / d["propagator_steps"] ** 2


def test_recheck_outside_the_tolerance_exits_1_with_one_line(stub_model_file, monkeypatch, capsys):
    """The tuning converges on its own plant, but the independent re-check (the unprepared plant with
    twice the steps, here biased by 0.05 >> tol 3e-4) misses rho_d +- tol: exit 1 with one line naming
    the re-check (a warning and exit 0 would accept gains that failed their check)."""
    from dataclasses import dataclass
    from typing import Optional

    import flexstab.tuning as tune

    @dataclass(frozen=True)
    class Fake:
        n_steps: int = 256
        drives: tuple = ("a", "b")
        bias: float = 0.0
        plant: Optional["Fake"] = None

        def spectral_measure(self, kp, kd):
            return 0.6 * math.exp(-0.1 * (sum(kp) + sum(kd))) + self.bias

    _use_plant(monkeypatch, tune, Fake(plant=Fake(bias=0.05)))
    argv = ["tune", "--model", "fake.py", "--target", "0.3", "--kp-range", "0", "10", "--kd-range", "0", "10"]
    assert cli_main(argv + ["--json"]) == 1
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["converged"] and abs(d["verified_spectral_radius"] - 0.35) <= 2 * d["tolerance"]
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and "check failed" in err[0] and "twice the propagator steps (512)" in err[0], err
    # the same plant without the biased independent path passes: exit 0, nothing on stderr
    _use_plant(monkeypatch, tune, Fake(plant=Fake()))
    assert cli_main(argv) == 0 and capsys.readouterr().err == ""


def test_check_failure_names_the_recheck_method():
    """The one-line reason names how the re-check was made (Hill path: the streamed product, not "twice
    the propagator steps"); a re-check within rho_d +- tol and a converged tuning give None."""
    from flexstab.tuning import check_failure

    d = {"converged": True, "message": "", "target": 0.3, "tolerance": 3e-4,
         "verified_spectral_radius": 0.3010, "verified_method": "magnus2, 32768 steps (streamed)"}
    msg = check_failure(d)
    assert "magnus2, 32768 steps (streamed)" in msg and "twice" not in msg and "0.301" in msg
    assert check_failure(dict(d, verified_spectral_radius=0.3002)) is None
    assert "not converged" in check_failure(dict(d, converged=False, message="budget"))
    assert "gave no value" in check_failure(dict(d, verified_spectral_radius=float("nan")))


def test_tune_records_a_step_choice_stopped_at_the_cap(stub_model_file, monkeypatch, capsys):
    """``tune --model`` carries the range-centre step choice (``propagator_choice``) and says when
    MAX_TUNING_STEPS stopped it short.  Fake r_n = exact + c / n^2 with c = 320: the last pair at the cap,
    (2048, 4096), estimates 4/3 |r_2048 - r_4096| = c / 2048^2 = 7.63e-5 > tol / 4 = 7.5e-5 (not met); at the
    tuned gains 4096 steps pass the check (c / 4096^2 = 1.9e-5), so the tuning itself succeeds."""
    from dataclasses import dataclass
    from types import SimpleNamespace

    import flexstab.tuning as tune
    from flexstab.plants import PlantChoice, propagator_choice

    @dataclass(frozen=True)
    class Fake:
        n_steps: int = 256
        drives: tuple = ("a", "b")

        def spectral_measure(self, kp, kd):
            return 1.0 / (1.0 + 0.1 * (sum(kp) + sum(kd))) + 320.0 / self.n_steps**2

    def choice(definition, orbit, lin, cfg):
        sc = propagator_choice(Fake(), cfg)
        return PlantChoice(sc.plant, steps=sc)

    base = SimpleNamespace(drives=Fake.drives, orbit=SimpleNamespace(model=None), linearization=None)
    import flexstab.plants as plants

    monkeypatch.setattr(tune, "build_plant", lambda *a, **k: base)
    monkeypatch.setattr(plants, "plant_choice_for", choice)
    argv = ["tune", "--model", "fake.py", "--target", "0.3", "--kp-range", "0", "10", "--kd-range", "0", "10"]
    with pytest.warns(RuntimeWarning, match="MAX_TUNING_STEPS"):
        assert cli_main(argv + ["--json"]) == 0
    pc = json.loads(capsys.readouterr().out)["propagator_choice"]
    assert pc["n_steps"] == 4096 and pc["converged"] is False
    assert pc["error_estimate"] == pytest.approx(320.0 / 2048**2, rel=1e-6) and pc["tolerance"] == pytest.approx(3e-4)
    with pytest.warns(RuntimeWarning):
        assert cli_main(argv) == 0
    assert ("warning: 4096 propagator steps (the cap) did not meet tolerance / 4 at the range centre "
            "(estimate 7.63e-05)") in capsys.readouterr().out
