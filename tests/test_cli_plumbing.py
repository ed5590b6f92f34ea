"""Command-line plumbing a user meets: pipes, killed parents, Exudyn chatter, reprs."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from flexstab.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}


def test_closed_pipe_is_not_an_error():
    """``flexstab floquet | head -0``: the reader is gone before we write; no traceback, no '[Errno 32]'."""
    p = subprocess.Popen([sys.executable, "-m", "flexstab.cli", "floquet"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, env=ENV, cwd=ROOT)
    p.stdout.close()  # the reader exits at once
    err = p.stderr.read().decode()
    rc = p.wait(timeout=120)
    assert "Broken pipe" not in err and "Traceback" not in err, err
    assert rc == 141


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its new parent) counts as gone
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="uses SIGKILL and /proc")
def test_pool_workers_exit_when_the_parent_is_killed(tmp_path):
    """SIGKILL of the process that owns a process pool: its workers end within a few poll intervals."""
    script = tmp_path / "parent.py"
    pids_file = tmp_path / "pids"
    script.write_text(
        "import os, signal, time\n"
        "from flexstab.executor import make_executor\n"
        "ex = make_executor('process', max_workers=2)\n"
        "futures = [ex.submit(time.sleep, 120) for _ in range(2)]\n"
        "time.sleep(1.0)\n"
        f"open({str(pids_file)!r}, 'w').write(' '.join(str(p) for p in ex._processes))\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    # workers inherit no pipe of ours, so waiting for the parent does not wait for them
    subprocess.run([sys.executable, str(script)], env=ENV, cwd=ROOT, timeout=120,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pids = [int(p) for p in pids_file.read_text().split()]
    assert len(pids) == 2
    from flexstab.executor import PARENT_POLL_INTERVAL

    deadline = time.monotonic() + 20 * PARENT_POLL_INTERVAL
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    left = [p for p in pids if _alive(p)]
    for p in left:  # do not leave them behind even when the test fails
        os.kill(p, signal.SIGKILL)
    assert not left, f"orphan workers still running: {left}"


def test_exudyn_warnings_go_to_stderr(capsys, monkeypatch):
    """Exudyn prints warnings through Python's stdout; ``modes`` keeps stdout for the table."""
    import mbs_models.modes as modes

    real = modes.exudyn_frequencies

    def chatty(*args, **kwargs):
        print("Python WARNING: the number of total coordinates (unknowns) is larger than 1000")
        return real(*args, **kwargs)

    monkeypatch.setattr(modes, "exudyn_frequencies", chatty)
    assert cli_main(["modes", "--elements", "2", "--count", "1"]) == 0
    out, err = capsys.readouterr()
    assert "WARNING" not in out and "WARNING" in err
    assert out.splitlines()[0].startswith("Exudyn ANCF link, 2 elements")


def test_zero_tip_mass_is_a_legitimate_link(tmp_path, capsys):
    """tip_mass = 0 (a bare link) runs end to end; its first clamped-free frequency is Euler-Bernoulli's.

    Reference: clamped-free beam without tip mass, f1 = (beta1 L)^2 / (2 pi L^2) sqrt(EI / (rho A)),
    beta1 L = 1.875104068711961 (root of 1 + cos x cosh x = 0).  Tolerance: the cubic ANCF element
    converges like h^4 in the frequency (README: 1e-6 at 8 elements), so 1.6e-5 at 4 elements; 1e-4 allows 6x.
    """
    from mbs_models.parameters import ManipulatorParameters

    f = tmp_path / "bare.toml"
    f.write_text("[manipulator]\ntip_mass = 0\n")
    assert cli_main(["floquet", "--config", str(f), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert math.isfinite(d["spectral_radius"]) and d["liouville_residual"] < 1e-10
    assert cli_main(["modes", "--config", str(f), "--elements", "4", "--count", "1", "--json"]) == 0
    f1 = json.loads(capsys.readouterr().out)["frequencies_hz"][0]
    p = ManipulatorParameters(tip_mass=0.0)
    bl = 1.875104068711961
    ref = bl**2 / (2 * math.pi * p.length**2) * math.sqrt(p.youngs_modulus * p.second_moment / (p.density * p.area))
    assert f1 == pytest.approx(ref, rel=1e-4)
    assert f1 != pytest.approx(17.205205, rel=1e-2)  # not the 0.1 kg tip-mass link's frequency
    f.write_text("[manipulator]\ntip_mass = -0.1\n")
    assert cli_main(["floquet", "--config", str(f)]) == 2  # negative masses are still rejected


def test_tuning_result_repr_is_short():
    from mbs_models import ReducedModel
    from taguchi import GainObjective, TuningConfig, taguchi_tune

    res = taguchi_tune(GainObjective(ReducedModel(omega=4 * math.pi)), TuningConfig(target=0.3))
    text = repr(res)
    assert len(text) < 300 and "\n" not in text and f"<{len(res.iterations)} TaguchiIteration>" in text
    assert len(repr(res.iterations)) < 200 * len(res.iterations)
    assert f"kp={res.kp:.6g}" in text
