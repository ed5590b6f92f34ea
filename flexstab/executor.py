"""Executors for independent evaluations (Taguchi runs, stability-chart sweeps).

One :class:`concurrent.futures.Executor` interface for three back ends:

* ``"serial"`` -- :class:`SerialExecutor`, runs each call at once in the
  calling process; best for a handful of millisecond-scale evaluations, where
  starting worker processes costs more than it saves;
* ``"process"`` -- :class:`concurrent.futures.ProcessPoolExecutor` on the
  local cores (the default for big jobs);
* ``"dask"`` -- a :mod:`distributed` cluster reached at a scheduler address
  such as ``tcp://127.0.0.1:8786`` (:class:`DaskExecutor`).

:func:`make_executor` picks one; every executor is a context manager
(``with make_executor(...) as ex:``) that releases its workers (and closes
its Dask client) on exit.  :func:`map_ordered` evaluates a function on a list
of items with a progress bar and returns the results in input order;
:func:`run_sweep` does the same but appends every finished point to a JSON
Lines file and skips already-stored points when restarted, so an interrupted
sweep loses no finished point.

Functions sent to ``"process"`` or ``"dask"`` executors must be picklable
(defined at module level, or :func:`functools.partial` of such); their
results must be picklable too, and for :func:`run_sweep` JSON-serialisable.
"""

from __future__ import annotations

import asyncio
import concurrent.futures as cf
import json
import logging
import math
import multiprocessing
import os
import re
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from flexstab.progress import make_bar
from flexstab.threads import blas_threads, limit_blas_threads
from stability.serialization import json_ready

__all__ = [
    "AUTO_SERIAL_MAX_TASKS",
    "DEFAULT_CONNECT_TIMEOUT",
    "EXECUTOR_KINDS",
    "DaskExecutor",
    "SerialExecutor",
    "SweepResult",
    "make_executor",
    "map_ordered",
    "point_key",
    "run_sweep",
    "validate_scheduler_address",
    "exit_with_parent",
    "worker_init",
    "PARENT_POLL_INTERVAL",
]

logger = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")

#: Executor kinds accepted by :func:`make_executor`.
EXECUTOR_KINDS: tuple[str, ...] = ("auto", "serial", "process", "dask")

#: With ``kind="auto"`` and ``n_tasks`` given, jobs of at most this many tasks
#: run serially: starting a process pool takes ~0.1-0.5 s, the cost of a few
#: dozen millisecond-scale Floquet evaluations (one L9/L25 array).
AUTO_SERIAL_MAX_TASKS: int = 32

#: Seconds to wait for a Dask scheduler to answer before giving up.
DEFAULT_CONNECT_TIMEOUT: float = 10.0

_ADDRESS_RE = re.compile(
    r"^(?:(?P<scheme>tcp|tls|inproc)://)?"
    r"(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9](?:[A-Za-z0-9.\-]*[A-Za-z0-9])?)"
    r"(?::(?P<port>[0-9]{1,5}))?(?P<path>/[A-Za-z0-9/\-_.]*)?$"
)


class SerialExecutor(cf.Executor):
    """An executor that runs every call immediately in the calling process.

    ``submit`` returns an already-finished :class:`concurrent.futures.Future`
    holding the result or the exception; ``map`` is the base-class one
    (every call made up front, results yielded in order).  ``shutdown`` only
    refuses further submissions.
    """

    def __init__(self) -> None:
        self._shutdown = False

    def submit(self, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> cf.Future[R]:
        """Run ``fn(*args, **kwargs)`` now; return a finished future."""
        if self._shutdown:
            raise RuntimeError("cannot schedule new futures after shutdown")
        future: cf.Future[R] = cf.Future()
        future.set_running_or_notify_cancel()
        try:
            result = fn(*args, **kwargs)
        except Exception as exc:  # stored on the future, as a pool would
            future.set_exception(exc)
        else:
            future.set_result(result)
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Refuse further submissions (nothing is ever pending)."""
        self._shutdown = True

    def __repr__(self) -> str:
        return "SerialExecutor()"


class DaskExecutor(cf.Executor):
    """:class:`concurrent.futures.Executor` on a :mod:`distributed` client.

    Wraps ``client.get_executor(pure=False)`` (every submission runs; Dask's
    result caching by argument hash is off) and closes the client on
    :meth:`shutdown` if this object opened it.

    Parameters
    ----------
    client : distributed.Client
    owns_client : bool
        Close ``client`` on shutdown.
    """

    def __init__(self, client: Any, owns_client: bool = True) -> None:
        self.client = client
        self._owns_client = owns_client
        # one BLAS thread per worker process (flexstab.threads), also on workers that join later
        from flexstab._dask_plugin import BlasThreadsPlugin

        client.register_plugin(BlasThreadsPlugin(blas_threads()), name="flexstab-blas-threads")
        self._inner = client.get_executor(pure=False)
        self._closed = False

    def submit(self, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> cf.Future[R]:
        """Submit ``fn(*args, **kwargs)`` to the cluster."""
        return self._inner.submit(fn, *args, **kwargs)

    def map(self, fn: Callable[..., R], *iterables: Iterable[Any], timeout: float | None = None,
            chunksize: int = 1) -> Iterable[R]:
        """Like :meth:`concurrent.futures.Executor.map`, on the cluster."""
        return self._inner.map(fn, *iterables, timeout=timeout)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Wait for (or cancel) submitted work, then close the client if owned."""
        if self._closed:
            return
        self._closed = True
        self._inner.shutdown(wait=wait and not cancel_futures)
        if self._owns_client:
            self.client.close()

    def __repr__(self) -> str:
        return f"DaskExecutor(scheduler={self.client.scheduler.address!r})"


def validate_scheduler_address(address: str) -> str:
    """Check a Dask scheduler address and return it with its scheme.

    Parameters
    ----------
    address : str
        ``tcp://HOST:PORT`` (also ``tls://``; ``HOST:PORT`` means ``tcp://``).
        HOST is a host name, an IPv4 address or a bracketed IPv6 address.

    Returns
    -------
    str
        The address with an explicit scheme, e.g. ``'tcp://127.0.0.1:8786'``.

    Raises
    ------
    ValueError
        If the address is malformed or the port is missing or out of range.
    """
    if not isinstance(address, str) or not address.strip():
        raise ValueError(f"scheduler address must be a non-empty string like tcp://HOST:PORT, got {address!r}")
    text = address.strip()
    m = _ADDRESS_RE.match(text)
    scheme = (m.group("scheme") if m else None) or "tcp"
    if m is None or (scheme != "inproc" and m.group("path")):
        raise ValueError(f"invalid scheduler address {address!r}; expected tcp://HOST:PORT, e.g. tcp://127.0.0.1:8786")
    if scheme == "inproc":
        return text
    port = m.group("port")
    if port is None:
        raise ValueError(f"scheduler address {address!r} has no port; expected tcp://HOST:PORT (Dask's default port is 8786)")
    if not 1 <= int(port) <= 65535:
        raise ValueError(f"scheduler address {address!r}: port {port} is not in 1..65535")
    return f"{scheme}://{m.group('host')}:{int(port)}"


def _connect(scheduler: str, timeout: float) -> DaskExecutor:
    address = validate_scheduler_address(scheduler)
    try:
        import distributed
    except ImportError as exc:  # pragma: no cover - optional dependency
        raise ImportError("a Dask scheduler needs the 'distributed' package: pip install flexstab[dask]") from exc
    logger.info("connecting to Dask scheduler %s (timeout %g s)", address, timeout)
    try:
        client = distributed.Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, asyncio.TimeoutError) as exc:
        raise ConnectionError(
            f"could not connect to the Dask scheduler at {address} within {timeout:g} s: {exc}"
        ) from exc
    return DaskExecutor(client, owns_client=True)


def make_executor(
    kind: str = "auto",
    max_workers: int | None = None,
    scheduler: str | Any | None = None,
    *,
    n_tasks: int | None = None,
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
    mp_context: str | None = None,
) -> cf.Executor:
    """Make an executor for independent evaluations.

    Parameters
    ----------
    kind : {'auto', 'serial', 'process', 'dask'}
        ``'auto'``: Dask if ``scheduler`` is given; else serial when
        ``max_workers == 1``, only one CPU is available, or ``n_tasks`` is at
        most :data:`AUTO_SERIAL_MAX_TASKS`; else a process pool.
    max_workers : int, optional
        Worker processes for ``'process'`` (default: the CPU count).  Ignored
        by ``'serial'`` and ``'dask'`` (the cluster decides).
    scheduler : str or distributed.Client, optional
        Dask scheduler address (``tcp://HOST:PORT``) or an existing client
        (which is then not closed on shutdown).  Required for ``'dask'``;
        not allowed with ``'serial'`` or ``'process'``.
    n_tasks : int, optional
        Expected number of tasks, used by ``'auto'`` only.
    connect_timeout : float
        Seconds to wait for the scheduler (default
        :data:`DEFAULT_CONNECT_TIMEOUT`).
    mp_context : str, optional
        Start method for the process pool (``'fork'``, ``'spawn'``,
        ``'forkserver'``); default the platform's.

    Returns
    -------
    concurrent.futures.Executor
        :class:`SerialExecutor`, :class:`~concurrent.futures.ProcessPoolExecutor`
        or :class:`DaskExecutor`; use it as a context manager.

    Raises
    ------
    ValueError
        Unknown kind, bad ``max_workers``, malformed scheduler address, or a
        scheduler combined with ``'serial'``/``'process'``.
    ConnectionError
        If the scheduler does not answer within ``connect_timeout``.
    """
    if kind not in EXECUTOR_KINDS:
        raise ValueError(f"unknown executor kind {kind!r}; choose one of {', '.join(EXECUTOR_KINDS)}")
    if max_workers is not None and (
        isinstance(max_workers, bool) or not isinstance(max_workers, (int, np.integer)) or max_workers < 1
    ):
        raise ValueError(f"max_workers must be a positive integer or None, got {max_workers!r}")
    if n_tasks is not None and (isinstance(n_tasks, bool) or not isinstance(n_tasks, (int, np.integer)) or n_tasks < 0):
        raise ValueError(f"n_tasks must be a non-negative integer or None, got {n_tasks!r}")
    if not (isinstance(connect_timeout, (int, float)) and math.isfinite(connect_timeout) and connect_timeout > 0):
        raise ValueError(f"connect_timeout must be a positive number of seconds, got {connect_timeout!r}")
    if scheduler is not None and kind in ("serial", "process"):
        raise ValueError(f"a scheduler address was given but kind={kind!r}; use kind='dask' or 'auto'")
    if kind == "dask" and scheduler is None:
        raise ValueError("kind='dask' needs a scheduler address like tcp://127.0.0.1:8786")

    if scheduler is not None:
        if hasattr(scheduler, "get_executor"):
            logger.debug("using the given Dask client %r", scheduler)
            return DaskExecutor(scheduler, owns_client=False)
        return _connect(scheduler, float(connect_timeout))
    if kind == "auto":
        cpus = os.cpu_count() or 1
        tiny = n_tasks is not None and n_tasks <= AUTO_SERIAL_MAX_TASKS
        kind = "serial" if (max_workers == 1 or cpus == 1 or tiny) else "process"
        logger.debug("auto executor: %s (n_tasks=%s, cpus=%d, max_workers=%s)", kind, n_tasks, cpus, max_workers)
    if kind == "serial":
        return SerialExecutor()
    context = multiprocessing.get_context(mp_context) if mp_context is not None else None
    return cf.ProcessPoolExecutor(max_workers=max_workers, mp_context=context,
                                  initializer=worker_init, initargs=(os.getpid(), blas_threads()))


def worker_init(parent_pid: int, blas: int) -> None:
    """Initializer of every pool worker: ``blas`` BLAS threads (:mod:`flexstab.threads`), SIGTERM's default
    action (the pool stops its workers with it; the parent's handler, inherited by a fork, is the CLI's),
    and end with the parent (:func:`exit_with_parent`)."""
    import signal

    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    limit_blas_threads(blas)
    exit_with_parent(parent_pid)


#: Seconds between two checks of the parent process by a pool worker (see :func:`exit_with_parent`).
PARENT_POLL_INTERVAL: float = 0.5


def exit_with_parent(parent_pid: int) -> None:
    """Worker initializer: end this worker when the process that started the pool dies.

    A pool's workers are normally stopped by their parent; a parent killed by SIGKILL cannot do it,
    and the workers would go on computing a chart nobody reads.  A daemon thread checks every
    :data:`PARENT_POLL_INTERVAL` s whether the parent is gone (the worker is then re-parented, so
    ``os.getppid()`` changes) and ends the worker.  (Linux's ``prctl(PR_SET_PDEATHSIG)`` is not
    used: it fires when the *thread* that started the worker ends, which for a pool need not be
    the death of the process.)
    """
    import threading
    import time

    if os.getppid() != parent_pid:  # the parent died before this worker started
        os._exit(1)
    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_INTERVAL)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="flexstab-parent-watchdog", daemon=True).start()


def _add_note(exc: BaseException, note: str) -> None:
    if hasattr(exc, "add_note"):  # Python >= 3.11
        exc.add_note(note)


def map_ordered(
    fn: Callable[[T], R],
    items: Iterable[T],
    executor: cf.Executor | None = None,
    *,
    progress: Any = False,
    desc: str | None = None,
) -> list[R]:
    """Evaluate ``fn`` on every item through ``executor``; results in input order.

    Parameters
    ----------
    fn : callable
        One-argument function; picklable for process or Dask executors.
    items : iterable
        Arguments, one call each.
    executor : concurrent.futures.Executor, optional
        Where to run; ``None`` or a :class:`SerialExecutor` runs the calls one
        after the other in this process (the bar then advances per call).
    progress : bool or callable
        Show a tqdm progress bar (on stderr), or a bar of this factory (:mod:`flexstab.progress`).
    desc : str, optional
        Label of the progress bar.

    Returns
    -------
    list
        ``[fn(item) for item in items]``.

    Raises
    ------
    Exception
        The first exception raised by ``fn`` (with a note naming the item);
        the calls not yet started are cancelled.
    """
    seq = list(items)
    if not seq:
        return []
    with make_bar(progress, total=len(seq), desc=desc, unit="runs") as bar:
        if executor is None or isinstance(executor, SerialExecutor):
            out = []
            for i, item in enumerate(seq):
                try:
                    out.append(fn(item))
                except Exception as exc:
                    _add_note(exc, f"while evaluating item {i}: {item!r}")
                    raise
                bar.update(1)
            return out
        futures = [executor.submit(fn, item) for item in seq]
        index = {f: i for i, f in enumerate(futures)}
        try:
            for f in cf.as_completed(futures):
                exc = f.exception()
                if exc is not None:
                    i = index[f]
                    _add_note(exc, f"while evaluating item {i}: {seq[i]!r}")
                    raise exc
                bar.update(1)
        except BaseException:
            for f in futures:
                f.cancel()
            raise
        return [f.result() for f in futures]


def point_key(point: Any) -> str:
    """Stable text key of a sweep point: canonical JSON of the point.

    Dictionaries are key-sorted, tuples and numpy arrays become lists, numpy
    scalars Python numbers, floats are written with ``repr`` (shortest string
    that round-trips), so equal points give equal keys in every run.  Note
    that ``1`` and ``1.0`` give different keys.

    Raises
    ------
    ValueError
        If the point is not JSON-serialisable.
    """
    try:
        return json.dumps(json_ready(point, finite=False), sort_keys=True, separators=(",", ":"))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"sweep point {point!r} is not JSON-serialisable: {exc}") from exc


@dataclass(frozen=True)
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes
    ----------
    points : tuple
        The points, in the order given.
    results : tuple
        ``fn(point)`` for each point, as decoded from the store's JSON (so a
        resumed sweep returns exactly what a fresh one does: lists, not
        tuples or arrays).
    n_loaded : int
        Distinct points found in the store and not recomputed.
    n_computed : int
        Distinct points computed in this call.
    store_path : str
        The JSON Lines file.
    """

    points: tuple[Any, ...]
    results: tuple[Any, ...]
    n_loaded: int
    n_computed: int
    store_path: str


def _load_store(path: Path) -> dict[str, Any]:
    """Read finished points; drop a partial last line left by a killed writer."""
    done: dict[str, Any] = {}
    if not path.exists():
        return done
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    if end < len(data):
        logger.warning("%s: dropping an incomplete last line (%d bytes) from an interrupted sweep",
                       path, len(data) - end)
        with open(path, "r+b") as fh:
            fh.truncate(end)
        data = data[:end]
    for lineno, line in enumerate(data.decode("utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            done[record["key"]] = record["result"]
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            warnings.warn(f"{path}:{lineno}: unreadable sweep record skipped ({exc})", RuntimeWarning, stacklevel=3)
    return done


def run_sweep(
    fn: Callable[[Any], Any],
    points: Sequence[Any],
    executor: cf.Executor | None,
    store_path: str | os.PathLike[str],
    *,
    progress: Any = False,
    desc: str | None = None,
) -> SweepResult:
    """Evaluate ``fn`` on every point, resumably, storing each result as it finishes.

    Each finished point is appended to ``store_path`` as one JSON line
    ``{"key": point_key(point), "point": point, "result": result}`` and
    flushed at once.  On a rerun the points whose key is already in the store
    are not recomputed, so a sweep killed at any moment loses at most the
    points that were running.  A partial last line (a kill during a write)
    is removed.  Duplicate points are computed once.

    Parameters
    ----------
    fn : callable
        One-argument function returning a JSON-serialisable result (numpy
        scalars and arrays are converted); picklable for process/Dask pools.
    points : sequence
        JSON-serialisable points (numbers, strings, lists, tuples, dicts).
    executor : concurrent.futures.Executor or None
        ``None`` or :class:`SerialExecutor`: run in this process.
    store_path : path-like
        JSON Lines file; created (with parent folders) if missing.
    progress, desc
        Progress bar over the points still to compute: ``True`` (tqdm) or a bar factory
        (:mod:`flexstab.progress`).

    Returns
    -------
    SweepResult

    Raises
    ------
    ValueError
        A point or result that is not JSON-serialisable.
    Exception
        The first exception raised by ``fn``; every point finished before (or
        alongside) it is stored first, points not started are cancelled.

    Notes
    -----
    Lines are flushed to the operating system, not fsync'ed: a killed process
    loses nothing, a power cut may.  Only one sweep should write a store at
    a time.
    """
    path = Path(store_path)
    pts = tuple(points)
    keys = [point_key(p) for p in pts]
    path.parent.mkdir(parents=True, exist_ok=True)
    done = _load_store(path)
    n_loaded = len({k for k in keys if k in done})
    todo: dict[str, Any] = {}
    for k, p in zip(keys, pts):
        if k not in done and k not in todo:
            todo[k] = p
    logger.info("sweep %s: %d points, %d stored, %d to compute", path, len(set(keys)), n_loaded, len(todo))

    def record(fh: Any, key: str, point: Any, result: Any) -> None:
        try:
            result_json = json_ready(result, finite=False)
            line = json.dumps({"key": key, "point": json_ready(point, finite=False), "result": result_json})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"result for point {point!r} is not JSON-serialisable: {exc}") from exc
        fh.write(line + "\n")
        fh.flush()
        done[key] = json.loads(json.dumps(result_json))

    with open(path, "a", encoding="utf-8") as fh, make_bar(progress, total=len(todo), desc=desc, unit="points") as bar:
        if executor is None or isinstance(executor, SerialExecutor):
            for key, point in todo.items():
                try:
                    result = fn(point)
                except Exception as exc:
                    _add_note(exc, f"while evaluating sweep point {point!r}")
                    raise
                record(fh, key, point, result)
                bar.update(1)
        else:
            futures = {executor.submit(fn, point): key for key, point in todo.items()}
            first_error: BaseException | None = None
            try:
                for f in cf.as_completed(futures):
                    if f.cancelled():
                        continue
                    exc = f.exception()
                    key = futures[f]
                    if exc is not None:
                        if first_error is None:
                            first_error = exc
                            _add_note(exc, f"while evaluating sweep point {todo[key]!r}")
                            for g in futures:
                                g.cancel()
                        continue
                    record(fh, key, todo[key], f.result())
                    bar.update(1)
            except BaseException:
                for g in futures:
                    g.cancel()
                raise
            if first_error is not None:
                raise first_error
    return SweepResult(
        points=pts,
        results=tuple(done[k] for k in keys),
        n_loaded=n_loaded,
        n_computed=len(todo),
        store_path=str(path),
    )
