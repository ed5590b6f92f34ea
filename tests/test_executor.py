"""Executors: serial, process pool and a Dask LocalCluster give equal results;
resumable sweeps lose no finished point and recompute none.

The oracle for every executor is a plain list comprehension in this process.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from flexstab.executor import (
    AUTO_SERIAL_MAX_TASKS,
    DaskExecutor,
    SerialExecutor,
    SweepResult,
    make_executor,
    map_ordered,
    point_key,
    run_sweep,
    validate_scheduler_address,
)

MAIN = Path(__file__).resolve().parents[1]


# -- module-level (picklable) work functions ----------------------------------------

def spectral_radius(point):
    """A small deterministic stand-in for a Floquet evaluation: max |eig(expm(A T))|."""
    kp, kd = point
    a = np.array([[0.0, 1.0], [-(1.0 + kp), -kd]])
    w = np.linalg.eigvals(a)
    return float(np.max(np.abs(np.exp(w * 2 * np.pi))))


def slow_identity(x):
    time.sleep(0.02 * (5 - x % 5))  # later items finish first
    return x


def fail_on_three(x):
    if x == 3:
        raise RuntimeError("boom at 3")
    return x * x


def square(x):
    return x * x


POINTS = [(kp, kd) for kp in (0.0, 5.0, 20.0) for kd in (0.0, 0.5, 3.0)]


def expected():
    return [spectral_radius(p) for p in POINTS]


# -- SerialExecutor ---------------------------------------------------------------

def test_serial_executor_semantics():
    with SerialExecutor() as ex:
        f = ex.submit(square, 4)
        assert f.done() and f.result() == 16
        g = ex.submit(fail_on_three, 3)
        assert isinstance(g.exception(), RuntimeError)
        assert list(ex.map(square, [1, 2, 3])) == [1, 4, 9]
    with pytest.raises(RuntimeError, match="shutdown"):
        ex.submit(square, 1)


# -- make_executor ----------------------------------------------------------------

def test_make_executor_kinds():
    assert isinstance(make_executor("serial"), SerialExecutor)
    assert isinstance(make_executor("auto", n_tasks=AUTO_SERIAL_MAX_TASKS), SerialExecutor)
    assert isinstance(make_executor("auto", max_workers=1), SerialExecutor)
    big = make_executor("auto", n_tasks=AUTO_SERIAL_MAX_TASKS + 1)
    with big:
        if (os.cpu_count() or 1) > 1:
            assert isinstance(big, cf.ProcessPoolExecutor)
    with make_executor("process", max_workers=2) as ex:
        assert isinstance(ex, cf.ProcessPoolExecutor)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"kind": "threads"}, "unknown executor kind"),
        ({"kind": "process", "max_workers": 0}, "max_workers"),
        ({"kind": "process", "max_workers": 1.5}, "max_workers"),
        ({"kind": "serial", "scheduler": "tcp://127.0.0.1:8786"}, "scheduler"),
        ({"kind": "dask"}, "scheduler address"),
        ({"kind": "auto", "scheduler": "http://127.0.0.1:8786"}, "invalid scheduler address"),
        ({"kind": "auto", "n_tasks": -1}, "n_tasks"),
        ({"kind": "dask", "scheduler": "tcp://127.0.0.1:8786", "connect_timeout": 0}, "connect_timeout"),
    ],
)
def test_make_executor_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_executor(**kwargs)


@pytest.mark.parametrize(
    "address, normalised",
    [
        ("tcp://127.0.0.1:8786", "tcp://127.0.0.1:8786"),
        ("127.0.0.1:8786", "tcp://127.0.0.1:8786"),
        ("tls://scheduler.example.org:9000", "tls://scheduler.example.org:9000"),
        ("tcp://[::1]:8786", "tcp://[::1]:8786"),
        (" tcp://node-01:8786 ", "tcp://node-01:8786"),
    ],
)
def test_scheduler_address_valid(address, normalised):
    assert validate_scheduler_address(address) == normalised


@pytest.mark.parametrize(
    "address",
    ["", "tcp://", "tcp://127.0.0.1", "tcp://127.0.0.1:0", "tcp://127.0.0.1:70000",
     "http://127.0.0.1:8786", "tcp://:8786", "tcp://host name:8786", "tcp://h:87/x", None],
)
def test_scheduler_address_invalid(address):
    with pytest.raises(ValueError):
        validate_scheduler_address(address)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_gives_clear_error_within_timeout():
    address = f"tcp://127.0.0.1:{_free_port()}"
    t0 = time.perf_counter()
    with pytest.raises(ConnectionError, match="could not connect to the Dask scheduler"):
        make_executor(scheduler=address, connect_timeout=0.5)
    assert time.perf_counter() - t0 < 10.0


# -- map_ordered ------------------------------------------------------------------

def test_map_ordered_serial_and_process_equal_oracle():
    oracle = expected()
    assert map_ordered(spectral_radius, POINTS, None) == oracle
    with make_executor("serial") as ex:
        assert map_ordered(spectral_radius, POINTS, ex, progress=True, desc="serial") == oracle
    with make_executor("process", max_workers=2) as ex:
        assert map_ordered(spectral_radius, POINTS, ex, progress=True, desc="process") == oracle


def test_map_ordered_keeps_input_order_when_completion_order_differs():
    with make_executor("process", max_workers=2) as ex:
        assert map_ordered(slow_identity, range(10), ex) == list(range(10))


def test_map_ordered_empty_and_errors():
    assert map_ordered(square, [], None) == []
    with pytest.raises(RuntimeError, match="boom at 3"):
        map_ordered(fail_on_three, range(6), None)
    with make_executor("process", max_workers=2) as ex:
        with pytest.raises(RuntimeError, match="boom at 3"):
            map_ordered(fail_on_three, range(6), ex)


# -- Dask --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def dask_cluster():
    distributed = pytest.importorskip("distributed")
    # one worker *process* on loopback: functions and results really cross a
    # process boundary through Dask's serialisation, as on a remote cluster
    cluster = distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=True, protocol="tcp",
        host="127.0.0.1", dashboard_address=None,
    )
    try:
        yield cluster
    finally:
        cluster.close()


def test_dask_equals_serial(dask_cluster, tmp_path):
    t0 = time.perf_counter()
    address = dask_cluster.scheduler_address
    assert address.startswith("tcp://127.0.0.1:")
    with make_executor(scheduler=address, connect_timeout=5) as ex:
        assert isinstance(ex, DaskExecutor)
        assert map_ordered(spectral_radius, POINTS, ex, progress=True, desc="dask") == expected()
        assert list(ex.map(square, range(5))) == [0, 1, 4, 9, 16]
        sweep = run_sweep(spectral_radius, POINTS, ex, tmp_path / "dask.jsonl")
    assert list(sweep.results) == expected()
    serial = run_sweep(spectral_radius, POINTS, None, tmp_path / "serial.jsonl")
    assert serial.results == sweep.results
    assert time.perf_counter() - t0 < 20.0


def test_dask_with_existing_client_is_not_closed(dask_cluster):
    distributed = pytest.importorskip("distributed")
    with distributed.Client(dask_cluster, set_as_default=False) as client:
        with make_executor("dask", scheduler=client) as ex:
            assert map_ordered(square, range(4), ex) == [0, 1, 4, 9]
        assert client.status == "running"


# -- point keys -------------------------------------------------------------------

def test_point_key_is_stable():
    assert point_key((1.0, 0.1)) == point_key([1.0, 0.1]) == point_key(np.array([1.0, 0.1]))
    assert point_key(np.float64(0.1)) == point_key(0.1) == "0.1"
    assert point_key({"kp": 1.0, "kd": 2.0}) == point_key({"kd": 2.0, "kp": 1.0})
    assert point_key(0.1 + 0.2) != point_key(0.3)  # exact float, no rounding
    with pytest.raises(ValueError, match="JSON"):
        point_key({1, 2})


# -- resumable sweeps ---------------------------------------------------------------

def _lines(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


def test_sweep_fresh_then_rerun_recomputes_nothing(tmp_path):
    store = tmp_path / "sub" / "sweep.jsonl"
    first = run_sweep(spectral_radius, POINTS, None, store)
    assert isinstance(first, SweepResult)
    assert first.n_computed == len(POINTS) and first.n_loaded == 0
    assert list(first.results) == expected()
    assert len(_lines(store)) == len(POINTS)
    calls = []
    second = run_sweep(lambda p: calls.append(p) or 0.0, POINTS, None, store)
    assert calls == [] and second.n_loaded == len(POINTS) and second.n_computed == 0
    assert second.results == first.results


def test_sweep_interrupted_by_error_loses_nothing_and_recomputes_nothing(tmp_path):
    store = tmp_path / "sweep.jsonl"

    def crash_at_five(p, _count=[0]):
        _count[0] += 1
        if _count[0] == 5:
            raise KeyboardInterrupt  # like Ctrl-C during the fifth evaluation
        return spectral_radius(p)

    with pytest.raises(KeyboardInterrupt):
        run_sweep(crash_at_five, POINTS, None, store)
    stored = {r["key"] for r in _lines(store)}
    assert stored == {point_key(p) for p in POINTS[:4]}

    calls = []

    def counting(p):
        calls.append(p)
        return spectral_radius(p)

    res = run_sweep(counting, POINTS, None, store)
    assert calls == POINTS[4:]  # exactly the unfinished points
    assert res.n_loaded == 4 and res.n_computed == len(POINTS) - 4
    assert list(res.results) == expected()
    keys = [r["key"] for r in _lines(store)]
    assert sorted(keys) == sorted(point_key(p) for p in POINTS)  # each point once


def test_sweep_process_pool_error_keeps_finished_points(tmp_path):
    store = tmp_path / "sweep.jsonl"
    pts = list(range(8))
    with make_executor("process", max_workers=2) as ex:
        with pytest.raises(RuntimeError, match="boom at 3"):
            run_sweep(fail_on_three, pts, ex, store)
    stored = {json.loads(r["key"]) for r in _lines(store)}
    assert 3 not in stored
    with make_executor("process", max_workers=2) as ex:
        res = run_sweep(square, pts, ex, store)
    assert res.n_loaded == len(stored) and res.n_computed == len(pts) - len(stored)
    assert list(res.results) == [x * x for x in pts]
    assert sorted(json.loads(r["key"]) for r in _lines(store)) == pts


def test_sweep_drops_partial_last_line(tmp_path):
    store = tmp_path / "sweep.jsonl"
    run_sweep(square, [1, 2, 3], None, store)
    with open(store, "a") as fh:
        fh.write('{"key": "4", "point": 4, "res')  # killed mid-write
    calls = []
    res = run_sweep(lambda x: calls.append(x) or x * x, [1, 2, 3, 4], None, store)
    assert calls == [4]
    assert list(res.results) == [1, 4, 9, 16]
    assert len(_lines(store)) == 4


def test_sweep_duplicates_and_json_results(tmp_path):
    store = tmp_path / "sweep.jsonl"
    calls = []

    def fn(p):
        calls.append(p)
        return {"rho": np.float64(p[0]) / 2, "mults": np.array([p[0], p[1]]), "pair": (1, 2)}

    res = run_sweep(fn, [(1.0, 2.0), (1.0, 2.0), (3.0, 4.0)], None, store)
    assert calls == [(1.0, 2.0), (3.0, 4.0)]
    assert res.results[0] == res.results[1] == {"rho": 0.5, "mults": [1.0, 2.0], "pair": [1, 2]}
    again = run_sweep(fn, [(3.0, 4.0), (1.0, 2.0)], None, store)
    assert again.results == (res.results[2], res.results[0])  # resumed == fresh
    with pytest.raises(ValueError, match="JSON"):
        run_sweep(lambda p: object(), [9.0], None, store)
    with pytest.raises(ValueError, match="JSON"):
        run_sweep(square, [{1, 2}], None, store)


def test_sweep_survives_a_real_kill(tmp_path):
    """SIGKILL a sweep in a child process, restart it: no finished point lost or redone."""
    if not hasattr(signal, "SIGKILL"):
        pytest.skip("needs SIGKILL")
    store = tmp_path / "killed.jsonl"
    n = 40
    script = textwrap.dedent(
        f"""
        import sys, time
        sys.path.insert(0, {str(MAIN)!r})
        from flexstab.executor import run_sweep
        def slow(x):
            time.sleep(0.05)
            return x * x
        run_sweep(slow, list(range({n})), None, {str(store)!r})
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if store.exists() and store.read_text().count("\n") >= 3:
                break
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=10)
    text = store.read_text()
    complete = text[: text.rfind("\n") + 1]  # a kill mid-write may leave a partial line
    finished = {json.loads(json.loads(line)["key"]) for line in complete.splitlines()}
    assert 3 <= len(finished) < n, "the child must be killed mid-sweep"
    calls = []
    res = run_sweep(lambda x: calls.append(x) or x * x, list(range(n)), None, store)
    assert sorted(calls) == sorted(set(range(n)) - finished)  # none redone
    assert list(res.results) == [x * x for x in range(n)]  # none lost
    keys = [json.loads(r["key"]) for r in _lines(store)]
    assert sorted(keys) == list(range(n))
