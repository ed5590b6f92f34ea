"""The command line's running contract (docs/running.md): BLAS threads, fast argument errors, a result-only
stdout, exit codes, the JSON typing rule of gains, frozen results, progress, the study's folder lock and its
interrupted manifest.  Each test also shows the wrong behaviour it rejects."""
from __future__ import annotations

import dataclasses
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

ROOT = Path(__file__).resolve().parent.parent


def _python(code: str, env_extra: dict | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "FLEXSTAB_BLAS_THREADS")}
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=timeout)


# ----------------------------------------------------------------------------- BLAS threads
_BLAS_PROBE = """
import json, sys
from flexstab.cli import main
rc = main(sys.argv[1:] if len(sys.argv) > 1 else {argv!r})
from threadpoolctl import threadpool_info
from flexstab.executor import make_executor
def pool_threads(_):
    from threadpoolctl import threadpool_info
    return [m["num_threads"] for m in threadpool_info() if m["user_api"] == "blas"]
with make_executor("process", max_workers=1) as ex:
    worker = list(ex.map(pool_threads, [0]))[0]
print(json.dumps({{"rc": rc, "here": [m["num_threads"] for m in threadpool_info() if m["user_api"] == "blas"],
                  "worker": worker}}), file=sys.stderr)
"""


def _blas(argv, env_extra=None) -> dict:
    p = _python(_BLAS_PROBE.format(argv=argv), env_extra)
    return json.loads(p.stderr.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: every BLAS runs one thread anyway")
def test_one_blas_thread_per_process_by_default_and_overridable():
    """Without any environment variable the CLI and its pool workers run one BLAS thread (the BLAS
    default is one per core: on main this reads the core count); --blas-threads and
    FLEXSTAB_BLAS_THREADS override it."""
    d = _blas(["floquet", "--json"])
    assert d["rc"] == 0 and d["here"] and set(d["here"]) == {1} and set(d["worker"]) == {1}
    d = _blas(["--blas-threads", "2", "floquet", "--json"])
    assert set(d["here"]) == {2} and set(d["worker"]) == {2}
    d = _blas(["floquet", "--json"], {"FLEXSTAB_BLAS_THREADS": "2"})
    assert set(d["here"]) == {2} and set(d["worker"]) == {2}


def test_blas_threads_value_is_checked():
    from flexstab.threads import blas_threads

    assert blas_threads(None, {}) == 1 and blas_threads("3", {}) == 3 and blas_threads(None, {"FLEXSTAB_BLAS_THREADS": "4"}) == 4
    for bad in ("0", "-1", "two"):
        with pytest.raises(ValueError, match="positive integer"):
            blas_threads(bad, {})


# ----------------------------------------------------------------------------- argument errors
_ARG_PROBE = """
import sys
from flexstab.cli import main
try:
    rc = main({argv!r})
except SystemExit as exc:
    rc = exc.code
heavy = sorted(m for m in ("numpy", "scipy", "exudyn") if m in sys.modules)
print("HEAVY", heavy, "RC", rc, file=sys.stderr)
"""


@pytest.mark.parametrize("argv, message", [
    (["validate", "--omega", "-2pi"], "omega must be positive"),
    (["floquet", "--omega", "-2pi"], "omega must be positive"),
    (["study", "--model", "missing.py"], "model file 'missing.py' not found"),
    (["tune", "--kp-range", "5", "1"], "--kp-range is empty or inverted"),
    (["chart", "--grid", "1"], "--grid must be >= 2"),
    (["validate", "--refinements", "9"], "--refinements must be <= 4"),
    (["--blas-threads", "0", "floquet"], "positive integer"),
])
def test_argument_errors_are_one_line_before_any_numerical_import(argv, message):
    p = _python(_ARG_PROBE.format(argv=argv))
    lines = p.stderr.strip().splitlines()
    assert lines[-1] == "HEAVY [] RC 2", p.stderr  # numpy, scipy, Exudyn were not imported
    assert len(lines) == 2 and message in lines[0]


def test_negative_omega_parses_as_a_value_not_an_option():
    from flexstab.options import parse_omega

    assert parse_omega("2pi") == pytest.approx(2 * math.pi) and parse_omega("+0.5pi") == pytest.approx(math.pi / 2)
    for text in ("-2pi", "-pi", "-3", "0"):
        with pytest.raises(ValueError, match="omega must be positive"):
            parse_omega(text)


# ----------------------------------------------------------------------------- stdout hygiene
def _exudyn_banner() -> None:
    """Exudyn's own console output: a solver run on a system with a massless free node."""
    import exudyn as exu
    from exudyn.itemInterface import MassPoint2D, NodePoint2D

    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    mbs.AddNode(NodePoint2D(referenceCoordinates=[0, 0]))
    mbs.AddObject(MassPoint2D(nodeNumber=mbs.AddNode(NodePoint2D(referenceCoordinates=[1, 0])), mass=1.0))
    mbs.Assemble()
    s = exu.SimulationSettings()
    s.timeIntegration.endTime, s.timeIntegration.numberOfSteps, s.timeIntegration.verboseMode = 0.1, 10, 0
    try:
        mbs.SolveDynamic(s)
    except Exception:  # noqa: BLE001 - the solver fails; what it printed is the point
        pass


@pytest.mark.slow
def test_json_stdout_holds_only_the_json_object(monkeypatch, capsys):
    import flexstab.commands.floquet as fq

    real = fq.floquet_report

    def noisy(args):
        _exudyn_banner()
        print("a library print")
        return real(args)

    monkeypatch.setattr(fq, "floquet_report", noisy)
    rc = cli_main(["floquet", "--json"])
    cap = capsys.readouterr()
    assert rc == 0 and isinstance(json.loads(cap.out), dict)  # one JSON object, nothing else
    assert "a library print" not in cap.err + cap.out and "singular" not in cap.err  # quiet without -v
    rc = cli_main(["-v", "floquet", "--json"])
    cap = capsys.readouterr()
    assert rc == 0 and isinstance(json.loads(cap.out), dict)
    assert "a library print" in cap.err and "singular" in cap.err  # with -v: Exudyn's warning on stderr


# ----------------------------------------------------------------------------- exit codes
def _validation_dict(**over) -> dict:
    d = {"diverged": False, "diverged_at": None, "reason": "", "agrees": True, "step_converged": True,
         "growth": None, "kp": 1.0, "kd": 0.5}
    d.update(over)
    return d


@pytest.mark.parametrize("over, rc, text", [
    ({}, 0, None),
    ({"agrees": False}, 1, "do not confirm"),
    ({"agrees": False, "diverged": True, "diverged_at": 0.0, "reason": "non-finite state"}, 1, "diverged at t = 0"),
    ({"growth": {"diverged": True, "reason": "run failed"}}, 1, "growth run diverged"),
])
def test_validate_exits_1_when_a_check_fails(monkeypatch, capsys, over, rc, text):
    import flexstab.commands.validate as val

    monkeypatch.setattr(val, "validation_report", lambda args: (_validation_dict(**over), None))
    monkeypatch.setattr(val, "_text", lambda d: "table")
    assert cli_main(["validate", "--kp", "1", "--kd", "0.5"]) == rc
    err = capsys.readouterr().err
    assert (text is None and "check failed" not in err) or (text in err and "check failed" in err)


def test_validation_failures_is_the_one_rule():
    from flexstab.checks import exit_code, validation_failures

    assert validation_failures(_validation_dict()) == [] and exit_code([]) == 0
    assert len(validation_failures(_validation_dict(agrees=False, diverged=True))) == 2 and exit_code(["x"]) == 1


# ----------------------------------------------------------------------------- JSON typing rule
@pytest.mark.slow
def test_gains_are_lists_in_every_command(capsys):
    assert cli_main(["floquet", "--kp", "2", "--kd", "1", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["kp"] == [2.0] and d["kd"] == [1.0]
    cli_main(["tune", "--max-evaluations", "30", "--json"])  # converged or not: the types are the point
    t = json.loads(capsys.readouterr().out)
    assert isinstance(t["kp"], list) and isinstance(t["kd"], list) and len(t["kp"]) == 1
    assert t["kp"] == [t["gains"][0]] and t["kd"] == [t["gains"][1]]


def test_gains_as_lists():
    from flexstab.options import gains_as_lists

    assert gains_as_lists({"kp": 2, "kd": (1.0, 2.0), "x": 3}) == {"kp": [2.0], "kd": [1.0, 2.0], "x": 3}
    assert gains_as_lists({"kp": None}) == {"kp": None}


# ----------------------------------------------------------------------------- frozen results
def test_results_hold_read_only_arrays_and_print_short():
    import numpy as np

    from mbs_models.reduced import ReducedModel
    from stability import floquet
    from taguchi.tuning import TuningConfig, taguchi_tune

    res = floquet(ReducedModel(2 * math.pi, kp=10.0, kd=2.0))
    with pytest.raises(ValueError, match="read-only"):
        res.multipliers[0] = 0
    with pytest.raises(ValueError, match="read-only"):
        res.monodromy[0, 0] = 0
    text = repr(res)
    assert "\n" not in text and len(text) < 1000 and "monodromy=<array 4x4 float64>" in text
    copy = np.array(res.multipliers)
    copy[0] = 0  # a copy is the caller's to change
    tuned = taguchi_tune(lambda g: 0.9 * math.exp(-0.02 * (g[0] + g[1])), TuningConfig(max_evaluations=30))
    assert all(not a.flags.writeable for a in vars(tuned).values() if isinstance(a, np.ndarray))


@dataclasses.dataclass(frozen=True)
class _PlainResult:
    """A frozen dataclass without :func:`stability.frozen.frozen_result` (module level: picklable)."""

    x: object


def test_a_result_back_from_a_worker_process_stays_read_only():
    """Unpickling (how a process pool returns a result) bypasses ``__init__``; the arrays must still be
    read-only and equal.  The check can fail: a plain frozen dataclass comes back writable."""
    import pickle

    import numpy as np

    from mbs_models.reduced import ReducedModel
    from stability import floquet

    res = floquet(ReducedModel(2 * math.pi, kp=10.0, kd=2.0))
    back = pickle.loads(pickle.dumps(res))
    np.testing.assert_array_equal(back.multipliers, res.multipliers)
    with pytest.raises(ValueError, match="read-only"):
        back.multipliers[0] = 0
    with pytest.raises(ValueError, match="read-only"):
        back.monodromy[0, 0] = 0

    plain = pickle.loads(pickle.dumps(_PlainResult(np.zeros(2))))
    plain.x[0] = 1.0  # what the decorator prevents


def test_frozen_result_leaves_the_callers_array_writable():
    from dataclasses import dataclass

    import numpy as np

    from stability.frozen import frozen_result

    @frozen_result
    @dataclass(frozen=True)
    class R:
        x: np.ndarray
        y: float = 1.0

    a = np.arange(100.0)
    r = R(a)
    a[0] = 5.0  # the caller's array stays writable ...
    with pytest.raises(ValueError):
        r.x[1] = 0.0  # ... the result's view does not
    assert repr(r) == "R(x=<array 100 float64>, y=1)"


# ----------------------------------------------------------------------------- progress
def test_line_progress_writes_one_line_per_step_at_most_every_interval():
    import io

    from flexstab.progress import MIN_INTERVAL, LineProgress

    now = [0.0]
    buf = io.StringIO()
    with LineProgress(total=10, desc="tune", unit="eval", stream=buf, clock=lambda: now[0]) as bar:
        for _ in range(10):
            now[0] += 0.5 * MIN_INTERVAL
            bar.update(1)
    lines = buf.getvalue().splitlines()
    assert lines[0] == f"tune: 2/10 eval (20 %), {MIN_INTERVAL:.1f} s" and lines[-1].startswith("tune: 10/10 eval (100 %)")
    assert len(lines) == 5  # every second step; the last step's line is not repeated on close
    odd = io.StringIO()
    now[0] = 0.0
    with LineProgress(total=3, stream=odd, clock=lambda: now[0]) as bar:
        for _ in range(3):
            now[0] += 0.6 * MIN_INTERVAL
            bar.update(1)
    assert [ln.split(":")[1].split()[0] for ln in odd.getvalue().splitlines()] == ["2/3", "3/3"]  # close: 3/3
    quick = io.StringIO()
    with LineProgress(total=3, stream=quick, clock=lambda: 0.0) as bar:
        bar.update(3)
    assert quick.getvalue() == ""  # a run shorter than the interval prints nothing


def test_tuning_reports_each_iteration_to_a_bar_factory():
    from taguchi.tuning import TuningConfig, taguchi_tune

    updates: list = []

    class Bar:
        def __init__(self, **kw):
            self.kw = kw

        def update(self, n):
            updates.append(n)

        def close(self):
            updates.append("closed")

    res = taguchi_tune(lambda g: 0.9 * math.exp(-0.02 * (g[0] + g[1])), TuningConfig(max_evaluations=60), progress=Bar)
    assert len(updates) == len(res.iterations) + 1 and updates[-1] == "closed"
    assert 0 < sum(updates[:-1]) <= res.evaluations


def test_progress_lines_on_a_pipe_and_tqdm_on_a_terminal():
    import io

    from flexstab.progress import LineProgress, progress_bars

    class Tty(io.StringIO):
        def isatty(self):
            return True

    assert progress_bars(io.StringIO()).func is LineProgress
    assert progress_bars(Tty()).func is not LineProgress


# ----------------------------------------------------------------------------- the study's folder
def test_a_busy_output_folder_is_refused_and_a_stale_lock_replaced(tmp_path, capsys):
    from flexstab.study import LOCK_FILE

    out = tmp_path / "study"
    out.mkdir()
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / LOCK_FILE).write_text(f"{sleeper.pid}\n")
        t0 = time.perf_counter()
        rc = cli_main(["study", "--quick", "--stages", "table2", "--out", str(out)])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and f"pid {sleeper.pid}" in err[0] and "in use" in err[0]
        assert not (out / "manifest.json").exists() and time.perf_counter() - t0 < 30
    finally:
        sleeper.kill()
        sleeper.wait()
    # the same lock once its process is gone: stale, replaced; the study runs and releases the folder
    assert cli_main(["study", "--quick", "--stages", "table2", "--out", str(out)]) == 0
    assert json.loads((out / "manifest.json").read_text())["status"] == "finished"
    assert not (out / LOCK_FILE).exists()


@pytest.mark.slow
def test_manifest_says_interrupted_after_sigterm(tmp_path):
    out = tmp_path / "study"
    env = {k: v for k, v in os.environ.items()}
    p = subprocess.Popen([sys.executable, "-m", "flexstab.cli", "study", "--quick", "--stages", "table3,charts",
                          "--jobs", "1", "--out", str(out)], stderr=subprocess.PIPE, stdout=subprocess.PIPE,
                         text=True, env=env, cwd=ROOT)
    try:
        manifest = out / "manifest.json"
        for line in p.stderr:  # the study's own stage lines (stderr is a pipe)
            if "table3 started" in line:
                break
        assert json.loads(manifest.read_text())["status"] == "running"
        time.sleep(1.0)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 143 and "interrupted (SIGTERM)" in err
    assert json.loads(manifest.read_text())["status"] == "interrupted"


def test_library_warnings_reach_the_terminal_as_one_line(capsys):
    """A warning the library raises while a command runs is one line ``flexstab CMD: warning: ...``
    (no source path, no code line); the format is restored afterwards.  The check can fail: Python's
    default format prints the file and line of the ``warnings.warn`` call."""
    import warnings

    from flexstab import cli

    before = warnings.formatwarning
    fmt = cli._one_line_warnings("floquet")
    text = fmt(RuntimeWarning("multipliers not certified\n to rtol 1e-06"), RuntimeWarning, "/x/plants.py", 278)
    assert text == "flexstab floquet: warning: multipliers not certified to rtol 1e-06\n"
    default = before("multipliers not certified", RuntimeWarning, "/x/plants.py", 278, "r = 1")
    assert "plants.py:278" in default and len(default.splitlines()) > 1
    # through the command (its own process: pytest records warnings in-process): an unreachable rtol
    import subprocess
    import sys
    from pathlib import Path

    model = Path(__file__).with_name("models") / "rigid_two_link.py"
    run = subprocess.run([sys.executable, "-c", "import sys; from flexstab.cli import main; sys.exit(main(sys.argv[1:]))",
                          "floquet", "--model", str(model), "--rtol", "1e-14"], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    warned = [ln for ln in run.stderr.splitlines() if "warning" in ln]
    assert warned and all(ln.startswith("flexstab floquet: warning: ") for ln in warned)
    assert ".py:" not in run.stderr and "RuntimeWarning" not in run.stderr
    assert warnings.formatwarning is before
