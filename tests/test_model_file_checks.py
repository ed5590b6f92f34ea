"""Model-file input checks: drive derivatives against finite differences, ``build`` returning ``None``,
``Assemble()`` inside ``build``, a massless free node; each one line and exit code 2 on the command line,
and each able to accept the correct model (so the check is not a blanket refusal)."""
from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from _bar_model import HEADER, TEMPLATE  # tests/ helper
from flexstab.cli import main as cli_main
from mbs_models.model_file import Drive, ModelFileError, build_model, load_model_file

#: A rigid bar on a revolute joint at O, driven in angle; MOTION is the drive's motion expression.
BAR = TEMPLATE.replace("DRIVES", '[{"name": "joint", "markers": (mg, ma), "motion": lambda t: MOTION}]')

GOOD = "(0.5 * math.sin(omega * t), 0.5 * omega * math.cos(omega * t), -0.5 * omega**2 * math.sin(omega * t))"
#: The issue's example: q is right, q_t and q_tt are arbitrary constants.
CONSTANTS = "(0.5 * math.sin(omega * t), 123.0, -9999.0)"
#: q_t with the wrong sign (q_tt right).
WRONG_SIGN = "(0.5 * math.sin(omega * t), -0.5 * omega * math.cos(omega * t), -0.5 * omega**2 * math.sin(omega * t))"
#: q_tt with the wrong sign (q_t right).
WRONG_ACCEL = "(0.5 * math.sin(omega * t), 0.5 * omega * math.cos(omega * t), 0.5 * omega**2 * math.sin(omega * t))"


def _file(tmp_path: Path, motion: str = GOOD, extra: str = "", text: str | None = None) -> Path:
    p = tmp_path / "model.py"
    p.write_text(text if text is not None else BAR.replace("MOTION", motion).replace("EXTRA", extra))
    return p


def _build_error(path: Path) -> str:
    with pytest.raises(ModelFileError) as info:
        build_model(load_model_file(path), 2 * math.pi)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


# ----------------------------------------------------------------------------- derivatives
@pytest.mark.parametrize("motion, what", [(CONSTANTS, "q_t = 123"), (WRONG_SIGN, "q_t = -3.14159"),
                                          (WRONG_ACCEL, "q_tt")])
def test_wrong_derivatives_are_rejected_naming_drive_and_time(tmp_path, motion, what):
    msg = _build_error(_file(tmp_path, motion))
    assert "drive 'joint'" in msg and re.search(r"at t = [0-9.e+-]+ s", msg)
    assert what in msg and "not the time derivative" in msg


def test_correct_derivatives_are_accepted(tmp_path):
    built = build_model(load_model_file(_file(tmp_path, GOOD)), 2 * math.pi)
    assert [d.name for d in built.drives] == ["joint"]


def test_wrong_derivatives_exit_2_with_one_line(tmp_path, capsys):
    rc = cli_main(["floquet", "--model", str(_file(tmp_path, CONSTANTS)), "--json"])
    cap = capsys.readouterr()
    assert rc == 2 and cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and "drive 'joint'" in lines[0] and "q_t = 123" in lines[0]


def _drive(fn, **extra) -> Drive:
    return Drive(name="d", markers=(0, 1), motion=fn, **extra)


def _triangle(T: float):
    """A triangle wave of period T (kinks at 0 and T/2) with its exact piecewise derivatives."""
    def motion(t):
        s = (t / T) % 1.0
        if s < 0.5:
            return 4 * s - 1, 4 / T, 0.0
        return 3 - 4 * s, -4 / T, 0.0
    return motion


def test_non_smooth_motion_passes_at_declared_breakpoints_only():
    from mbs_models.model_file import check_derivatives

    T = 1.0
    with pytest.raises(ModelFileError, match="q_t = .* not the time derivative"):
        check_derivatives(_drive(_triangle(T)), T)  # t = 0 and T/2 straddle the kinks
    check_derivatives(_drive(_triangle(T), breakpoints=(0.0, 0.5 * T)), T)
    # a breakpoint given outside [0, T) counts modulo T
    check_derivatives(_drive(_triangle(T), breakpoints=(3.0 * T, 2.5 * T)), T)


def test_motion_advancing_whole_turns_is_checked_like_a_periodic_one():
    from mbs_models.model_file import check_derivatives

    T, w = 0.5, 2 * math.pi / 0.5
    check_derivatives(_drive(lambda t: (w * t + 0.1 * math.sin(w * t), w + 0.1 * w * math.cos(w * t),
                                        -0.1 * w**2 * math.sin(w * t))), T)
    with pytest.raises(ModelFileError, match="not the time derivative"):
        check_derivatives(_drive(lambda t: (w * t, -w, 0.0)), T)


def test_derivative_check_accepts_high_harmonics_within_its_error_bound():
    """The central difference's truncation error for harmonic k is (2 pi k h/T)^2/6 relative: for k = 40
    (1e-3 x 0.17) it is far inside DERIVATIVE_TOLERANCE, and a 1 % error in q_t is still rejected."""
    from mbs_models.model_file import DERIVATIVE_TOLERANCE, check_derivatives

    T, k = 1.0, 40
    w = 2 * math.pi * k / T

    def motion(t, f=1.0):
        return math.sin(w * t), f * w * math.cos(w * t), -w**2 * math.sin(w * t)

    check_derivatives(_drive(motion), T)
    with pytest.raises(ModelFileError):
        check_derivatives(_drive(lambda t: motion(t, 1.0 + 10 * DERIVATIVE_TOLERANCE)), T)


# ----------------------------------------------------------------------------- build's contract
def test_build_returning_none_is_rejected(tmp_path):
    text = HEADER + "def build(mbs, omega):\n    mbs.AddNode(NodePointGround())\n"
    msg = _build_error(_file(tmp_path, text=text))
    assert "returned None" in msg and "[]" in msg
    text_ok = HEADER + ("def build(mbs, omega):\n    n = mbs.AddNode(NodePoint2D(referenceCoordinates=[0, 0]))\n"
                        "    mbs.AddObject(MassPoint2D(nodeNumber=n, mass=1.0))\n    return []\n")
    assert build_model(load_model_file(_file(tmp_path, text=text_ok)), 2 * math.pi).drives == ()


def test_assemble_inside_build_is_rejected(tmp_path):
    msg = _build_error(_file(tmp_path, extra="mbs.Assemble()"))
    assert "called mbs.Assemble()" in msg


def test_massless_free_node_is_named(tmp_path, capsys):
    extra = 'mbs.AddNode(NodePoint2D(referenceCoordinates=[1.0, 0], name="loose end"))'
    path = _file(tmp_path, extra=extra)
    rc = cli_main(["floquet", "--model", str(path), "--json"])
    cap = capsys.readouterr()
    assert rc == 2 and cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and "massless free node" in lines[0] and "'loose end'" in lines[0]
    # the same node with a mass is a valid model
    ok = _file(tmp_path, extra=extra.replace("mbs.AddNode(", "ln = mbs.AddNode(")
               + "\n    mbs.AddObject(MassPoint2D(nodeNumber=ln, mass=0.1))")
    from linearize.exudyn_system import ExudynSystem

    assert ExudynSystem(build_model(load_model_file(ok), 2 * math.pi)).n == 5


@pytest.mark.slow
def test_study_of_a_massless_free_node_says_so_once(tmp_path):
    """The whole study of such a model: one line naming the node, exit code 2, nothing on stdout -- not
    Exudyn's solver banner on stdout and a "redundant constraints" diagnosis once per stage."""
    import os
    import subprocess
    import sys

    path = _file(tmp_path, extra='mbs.AddNode(NodePoint2D(referenceCoordinates=[1.0, 0], name="loose end"))')
    env = {**os.environ, "MPLBACKEND": "Agg"}
    r = subprocess.run([sys.executable, "-m", "flexstab.cli", "study", "--model", str(path), "--quick", "--out",
                        str(tmp_path / "out")], capture_output=True, text=True, env=env, timeout=600)
    errors = [ln for ln in r.stderr.splitlines() if "error" in ln or "failed" in ln]
    assert r.returncode == 2 and r.stdout == ""
    assert len(errors) == 1 and "massless free node" in errors[0] and "'loose end'" in errors[0]
    assert "redundant constraints" not in r.stderr and "SOLVER FAILED" not in r.stderr
