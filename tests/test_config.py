"""User configuration files and CLI option parsing."""
from __future__ import annotations

import json
import math

import pytest

from flexstab.cli import main as cli_main
from flexstab.config import StudyConfig, load_config
from flexstab.options import parse_omega


@pytest.mark.parametrize("text, value", [("2pi", 2 * math.pi), ("0.5pi", 0.5 * math.pi), ("pi", math.pi),
                                         ("6.5", 6.5), ("3*pi", 3 * math.pi), (" 8PI ", 8 * math.pi)])
def test_parse_omega(text, value):
    assert parse_omega(text) == pytest.approx(value, rel=1e-15)


@pytest.mark.parametrize("text", ["", "abc", "-2pi", "0", "nan", "inf", "2pix"])
def test_parse_omega_rejects(text):
    with pytest.raises(ValueError, match="omega"):
        parse_omega(text)


def test_config_round_trip(tmp_path):
    f = tmp_path / "m.toml"
    f.write_text('[manipulator]\nlength = 1.2\ntip_mass = 0.2\n\n[study]\nomega = "4pi"\ntarget = 0.25\n'
                 'kp_range = [1, 50]\nelements = 6\n')
    cfg = load_config(f)
    assert cfg.manipulator.length == 1.2 and cfg.manipulator.tip_mass == 0.2
    assert cfg.manipulator.area == 4e-4  # untouched: Table 1
    assert cfg.omega == pytest.approx(4 * math.pi) and cfg.target == 0.25
    assert cfg.kp_range == (1.0, 50.0) and cfg.kd_range == (0.0, 40.0) and cfg.elements == 6


@pytest.mark.parametrize(
    "text, word",
    [
        ("[manipulator]\nlenght = 1.0\n", "lenght"),
        ("[manipulatr]\n", "manipulatr"),
        ("[study]\nfoo = 1\n", "foo"),
        ("[manipulator]\ntip_mass = -0.1\n", "tip_mass"),
        ("[manipulator]\nlength = nan\n", "length"),
        ("[study]\nkp_range = [10, 1]\n", "kp_range"),
        ("[study]\nkd_range = [-1, 1]\n", "kd_range"),
        ("[study]\nomega = \"-pi\"\n", "omega"),
        ("[study]\nelements = 0\n", "elements"),
        ("[study]\ntarget = 0\n", "target"),
        ("this is not toml", "TOML"),
    ],
)
def test_bad_config(tmp_path, text, word):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ValueError, match=word):
        load_config(f)


def test_cli_bad_config_is_one_line_exit_2(tmp_path, capsys):
    f = tmp_path / "bad.toml"
    f.write_text("[manipulator]\ndensity = 0\n")
    assert cli_main(["floquet", "--config", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "density" in err[0]


def test_cli_missing_config(tmp_path, capsys):
    assert cli_main(["floquet", "--config", str(tmp_path / "none.toml")]) == 2
    assert "cannot read config file" in capsys.readouterr().err


def test_config_changes_the_model(tmp_path, capsys):
    f = tmp_path / "heavy.toml"
    f.write_text("[manipulator]\ntip_mass = 0.3\n")
    cli_main(["floquet", "--json"])
    default = json.loads(capsys.readouterr().out)["spectral_radius"]
    cli_main(["floquet", "--json", "--config", str(f)])
    heavy = json.loads(capsys.readouterr().out)["spectral_radius"]
    assert heavy != pytest.approx(default, rel=1e-3)


def test_default_config_is_the_paper():
    cfg = StudyConfig()
    assert cfg.omega == pytest.approx(2 * math.pi) and cfg.target == 0.3


@pytest.mark.parametrize("argv", [["floquet", "--kp", "-1"], ["floquet", "--omega", "0"], ["nosuch"],
                                  ["floquet", "--method", "rk4"], ["tune", "--array", "L7"]])
def test_cli_usage_errors_are_one_line(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        raise SystemExit(cli_main(argv))
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "error" in err[0] and "Traceback" not in err[0]


def test_cli_non_converging_orbit_is_one_line_exit_1(tmp_path, capsys):
    """A link so soft (E = 2e7 N/m^2, 1 element, 2 pi) that Newton finds no periodic orbit from its guesses,
    nor continuation in omega a start at omega/2, /4 or /8: one line naming the cause, exit code 1, in
    seconds (~1.5 s CPU; the continuation halves its start at most twice).  The
    message says "did not converge", never that no orbit exists: one does (reached by continuation in
    material damping from the damped link's attracting orbit; confirmed by Exudyn's integrator at 64
    samples), the solver's guesses do not reach it."""
    f = tmp_path / "soft.toml"
    f.write_text("[manipulator]\nyoungs_modulus = 2e7\n")
    rc = cli_main(["floquet", "--model", "exudyn", "--elements", "1", "--config", str(f)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and "OrbitConvergenceError" in err[0] and "did not converge" in err[0]
