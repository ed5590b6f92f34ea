"""The stage runner of the studies: run, record, reuse.

A *stage* (:class:`Stage`) is a name, its inputs (a JSON-ready mapping, or a function giving one
when the stage is about to run, so that a stage can depend on what an earlier stage produced), the
function that computes it and the files it writes (:class:`StageOutput`).  :class:`StageRunner`
runs stages into one output folder:

- before a stage runs, the hash of its inputs (:func:`flexstab.provenance.inputs_hash`) is compared
  with its record ``<stage>.stage.json``; when they match and every file the record names is still
  the one the stage wrote, the stage is *reused* (not run; its record stays);
- otherwise its old record is removed, the stage runs and, when it returns, its record is written
  (inputs and their hash, report blocks, the SHA-256 of each file, wall and CPU time, failed checks);
  a stage that raises is *failed* (no record: the next run computes it again) and the runs go on;
- ``manifest.json`` says which stages the folder's report describes, with their inputs hashes, and how
  the run ended: ``"running"``, ``"finished"``, ``"interrupted"`` (Ctrl-C or SIGTERM) or ``"failed"``.

The paper's study (:mod:`flexstab.study`) and the study of a model file (:mod:`flexstab.model_study`)
run on it; :func:`folder_lock` keeps one study per folder.  Stages may also run in processes of their
own (:meth:`StageRunner.run`, ``lanes``): every record is still written by this process.
"""
from __future__ import annotations

import contextlib
import logging
import os
import resource
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Optional, Sequence, Union

from flexstab import provenance as pv
from flexstab.report import text

__all__ = ["Stage", "StageOutput", "StageRun", "StageRunner", "StudyResult", "folder_lock", "LOCK_FILE",
           "cpu_now", "stage_section", "STATUS_CHECK_FAILED"]

logger = logging.getLogger(__name__)

#: Status of a stage that computed but whose check failed (exit code 1; the record keeps the failures).
STATUS_CHECK_FAILED = "check failed"


@dataclass(frozen=True)
class StageOutput:
    """What a stage function returns.

    Attributes
    ----------
    json : str or None
        Its data JSON (a file name in the output folder).
    blocks : list
        Its report blocks (:mod:`flexstab.report`).
    title : str, optional
        Its section title (default: the stage's own).
    files : tuple of str
        Every other file it wrote that the report relies on (figures in ``blocks`` are added).
    check_failures : tuple of str
        Checks that failed although the stage computed (status ``"check failed"``), one line each.
    notes : tuple of str
        Notes for the section and the study's summary (one line each).
    """

    json: Optional[str]
    blocks: list
    title: Optional[str] = None
    files: tuple = ()
    check_failures: tuple = ()
    notes: tuple = ()

    @classmethod
    def of(cls, r: Union["StageOutput", Mapping[str, Any]]) -> "StageOutput":
        """``r`` itself, or a stage's dict (keys as the attributes) as a :class:`StageOutput`."""
        if isinstance(r, StageOutput):
            return r
        return cls(json=r.get("json"), blocks=list(r.get("blocks") or []), title=r.get("title"),
                   files=tuple(r.get("files") or ()), check_failures=tuple(r.get("check_failures") or ()),
                   notes=tuple(r.get("notes") or ()))

    @property
    def all_files(self) -> list[str]:
        """Every file of the stage (its JSON, ``files`` and the figures of its blocks)."""
        return pv.stage_files(self.json, self.files, self.blocks)


@dataclass(frozen=True)
class Stage:
    """One stage: a name, its inputs and the function that computes it.

    Attributes
    ----------
    name : str
        Also the name of its record (``<name>.stage.json``).
    fn : callable
        ``fn() -> StageOutput`` (or a dict of its fields).  A stage run in another process
        (:meth:`StageRunner.run`, ``lanes``) needs a picklable ``fn`` (e.g. a ``functools.partial`` of
        a module-level function).
    inputs : mapping or callable
        What decides its results (JSON-ready), hashed into its inputs hash; a callable is evaluated
        when the stage is about to run.
    title : str
        Section title when the stage gives none.
    """

    name: str
    fn: Callable[[], Any]
    inputs: Union[Mapping[str, Any], Callable[[], Mapping[str, Any]]]
    title: str = ""


@dataclass(frozen=True)
class StageRun:
    """What happened to one stage in this run.

    ``status`` is ``"computed"``, ``"reused"``, ``"check failed"`` (computed or reused, a check failed)
    or ``"failed"``; ``reused`` says whether its record was reused; ``record`` is its stage record
    (``None`` for a failed stage).
    """

    name: str
    status: str
    inputs_hash: str
    elapsed: float
    cpu: Optional[float] = None
    json: Optional[str] = None
    error: Optional[str] = None
    note: Optional[str] = None
    record: Optional[dict] = field(default=None, repr=False)
    reused: bool = False

    @property
    def ok(self) -> bool:
        """Whether the stage produced its files (computed or reused, checks passed or not)."""
        return self.status != "failed"

    def summary(self) -> dict:
        """The stage's entry in the study's summary (``study.json``'s ``stages``)."""
        if self.status == "failed":
            return {"status": "failed", "error": self.error, "elapsed": self.elapsed}
        d: dict = {"status": self.status, "json": self.json, "elapsed": self.elapsed, "cpu": self.cpu}
        if self.note:
            d["note"] = self.note
        if self.error:
            d["error"] = self.error
        return d

    def manifest_entry(self) -> dict:
        """The stage's entry in ``manifest.json``."""
        if self.status == "failed":
            return {"status": "failed", "error": self.error, "inputs_hash": self.inputs_hash, "elapsed": self.elapsed}
        if self.reused:
            return {"status": "reused", "inputs_hash": self.inputs_hash, "elapsed": 0.0}
        d = {"status": self.status, "inputs_hash": self.inputs_hash, "elapsed": self.elapsed, "cpu": self.cpu}
        if self.error:
            d["error"] = self.error
        return d


@dataclass(frozen=True)
class StudyResult:
    """Where a study's report went and what each stage produced (or why it failed)."""

    out: Path
    report_md: Path
    report_html: Path
    stages: dict
    elapsed: float

    def __repr__(self) -> str:
        status = ", ".join(f"{k}: {v.get('status', '?')}" for k, v in self.stages.items())
        return f"StudyResult(out={str(self.out)!r}, elapsed={self.elapsed:.1f} s, stages=[{status}])"


def cpu_now() -> float:
    """CPU seconds of this process and of its finished (waited-for) child processes."""
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def _execute(fn: Callable[[], Any]) -> tuple[StageOutput, float, float]:
    """Run a stage function; its output, wall and CPU seconds (this process + its pools)."""
    ts, cs = time.perf_counter(), cpu_now()
    r = StageOutput.of(fn())
    return r, time.perf_counter() - ts, cpu_now() - cs


def _one_line(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"


def _as_is(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


class StageRunner:
    """Runs stages into ``out``, writing their records and ``manifest.json`` (see the module docstring).

    Parameters
    ----------
    out : Path
        The (locked, :func:`folder_lock`) output folder.
    manifest : dict
        The manifest's fields besides ``status``, ``started_at`` and ``stages`` (e.g. the configuration
        and its hash); written at once with ``"status": "running"``.
    order : sequence of str
        Stage order of the manifest (stages not named follow in the order they ran).
    resume : bool
        Reuse stages whose records are valid for their inputs (default True).
    log : callable, optional
        Called with one line when a stage starts, finishes, fails or is reused.
    tag : callable, optional
        ``tag(name)`` starts each line (default ``"study: <name>"``).
    record_fields : mapping
        Written into every record; a record is reused only when it carries the same values.
    stamp : bool
        Add ``"study": {config_hash, inputs_hash, stage}`` to each stage's data JSON (with
        ``record_fields["config_hash"]``).
    bar : object, optional
        A progress bar (``update``, ``set_postfix_str``): one step per stage.
    reraise : tuple of exception types
        Raised through instead of recording the stage as failed (e.g. a bad model file: bad input).
    one_line_errors : bool
        Collapse the whitespace of an error message (default: as ``str(exc)``).
    """

    def __init__(self, out: Path, manifest: Mapping[str, Any], *, order: Sequence[str] = (), resume: bool = True,
                 log: Optional[Callable[[str], None]] = None, tag: Optional[Callable[[str], str]] = None,
                 record_fields: Mapping[str, Any] = (), stamp: bool = True, bar: Any = None,
                 reraise: tuple = (), one_line_errors: bool = False) -> None:
        self.out = Path(out)
        self.order = list(order)
        self.resume = resume
        self.say = log or (lambda line: None)
        self.tag = tag or (lambda name: f"study: {name}")
        self.record_fields = dict(record_fields)
        self.stamp = stamp
        self.bar = bar
        self.reraise = tuple(reraise)
        self.format_error = _one_line if one_line_errors else _as_is
        self.runs: dict[str, StageRun] = {}
        self._lock = threading.RLock()
        self.manifest = dict(manifest)
        self.manifest.update(started_at=pv.now(), status="running", stages={})
        self.write_manifest()

    # ------------------------------------------------------------------ manifest
    def write_manifest(self) -> None:
        with self._lock:
            names = [n for n in self.order if n in self.runs] + [n for n in self.runs if n not in self.order]
            self.manifest["stages"] = {n: self.runs[n].manifest_entry() for n in names}
            pv.write_manifest(self.out, self.manifest)

    def finish(self, **fields: Any) -> None:
        """Record the run as finished (with ``fields``, e.g. elapsed and CPU seconds)."""
        self.manifest.update(status="finished", finished_at=pv.now(), **fields)
        self.write_manifest()

    def stop(self, exc: BaseException, elapsed: float) -> None:
        """Record how an unfinished run ended: ``"interrupted"`` (KeyboardInterrupt) or ``"failed"``."""
        self.manifest.update({"status": "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed",
                              "finished_at": pv.now(), "elapsed": elapsed})
        try:
            self.write_manifest()
        except OSError:
            pass

    def summaries(self) -> dict:
        """``{name: StageRun.summary()}`` in stage order."""
        names = [n for n in self.order if n in self.runs] + [n for n in self.runs if n not in self.order]
        return {n: self.runs[n].summary() for n in names}

    # ------------------------------------------------------------------ one stage
    def prepare(self, stage: Stage) -> Optional[tuple[dict, str]]:
        """The stage's inputs and their hash; ``None`` (the stage recorded as reused) if its record is valid."""
        inputs = dict(stage.inputs() if callable(stage.inputs) else stage.inputs)
        ihash = pv.inputs_hash(inputs)
        rec = pv.load_record(self.out, stage.name)
        if (self.resume and pv.record_valid(self.out, rec, ihash)
                and all(rec.get(k) == v for k, v in self.record_fields.items())):
            self.say(f"{self.tag(stage.name)} reused (inputs unchanged since {rec['finished_at']})")
            checks = list(rec.get("check_failures") or [])
            notes = list(rec.get("notes") or [])
            run = StageRun(stage.name, STATUS_CHECK_FAILED if checks else "reused", ihash, rec["elapsed"],
                           rec.get("cpu"), rec["json"], "; ".join(checks) or None, "; ".join(notes) or None, rec,
                           reused=True)
            self._done(run)
            return None
        pv.record_path(self.out, stage.name).unlink(missing_ok=True)
        self.say(f"{self.tag(stage.name)} started")
        return inputs, ihash

    def failed(self, stage: Stage, ihash: str, exc: BaseException, elapsed: float) -> StageRun:
        err = self.format_error(exc)
        logger.error("stage %s failed: %s", stage.name, err)
        logger.debug("%s", "".join(traceback.format_exception(exc)))
        self.say(f"{self.tag(stage.name)} failed after {elapsed:.1f} s: {err}")
        run = StageRun(stage.name, "failed", ihash, elapsed, error=err)
        self._done(run)
        return run

    def finished(self, stage: Stage, inputs: dict, ihash: str, r: StageOutput, elapsed: float,
                 cpu: float) -> StageRun:
        missing = [f for f in r.all_files if not (self.out / f).is_file()]
        if missing:  # the record would name a file the stage did not write: the stage failed
            return self.failed(stage, ihash, FileNotFoundError(f"the stage wrote no {', '.join(missing)}"), elapsed)
        if self.stamp and r.json:
            pv.stamp_json(self.out / r.json, {"config_hash": self.record_fields.get("config_hash"),
                                              "inputs_hash": ihash, "stage": stage.name})
        files = {f: pv.file_sha(self.out / f) for f in r.all_files}
        checks, notes = list(r.check_failures), list(r.notes)
        record = {"stage": stage.name, "title": r.title or stage.title or stage.name, **self.record_fields,
                  "inputs_hash": ihash, "inputs": inputs, "json": r.json, "blocks": r.blocks, "files": files,
                  "elapsed": elapsed, "cpu": cpu, "finished_at": pv.now(), "check_failures": checks}
        if notes:
            record["notes"] = notes
        pv.write_record(self.out, record)
        self.say(f"{self.tag(stage.name)} finished in {elapsed:.1f} s"
                 + (f"; check failed: {'; '.join(checks)}" if checks else ""))
        run = StageRun(stage.name, STATUS_CHECK_FAILED if checks else "computed", ihash, elapsed, cpu, r.json,
                       "; ".join(checks) or None, "; ".join(notes) or None, record)
        self._done(run)
        return run

    def _done(self, run: StageRun) -> None:
        with self._lock:
            self.runs[run.name] = run
        self.write_manifest()
        if self.bar is not None:
            with self._lock:
                self.bar.set_postfix_str(run.name)
                self.bar.update(1)

    def run_stage(self, stage: Stage) -> StageRun:
        """Run (or reuse) ``stage`` in this process."""
        p = self.prepare(stage)
        if p is None:
            return self.runs[stage.name]
        ts = time.perf_counter()
        try:
            r, el, cpu = _execute(stage.fn)
        except self.reraise:
            raise
        except Exception as exc:  # a failed stage is reported, the study goes on
            return self.failed(stage, p[1], exc, time.perf_counter() - ts)
        return self.finished(stage, p[0], p[1], r, el, cpu)

    # ------------------------------------------------------------------ several processes
    def run(self, here: Sequence[Stage], lanes: Sequence[Sequence[Stage]] = (), *,
            preload: Optional[Callable[[], None]] = None, initializer: Optional[Callable] = None,
            initargs: tuple = ()) -> None:
        """Run ``here`` in this process, in order, and each of ``lanes`` (a chain of stages, in order) in a
        process of its own (forked once, after ``preload``, with ``initializer(*initargs)``) at the same time.

        Interrupted (Ctrl-C, SIGTERM as KeyboardInterrupt) or failed: the manifest says so, the lane
        processes are stopped at once, and the exception is raised.
        """
        pools: list = []
        helpers: list = []
        lane_error: list = []
        stopping = threading.Event()
        t0 = time.perf_counter()
        lanes = [list(c) for c in lanes if c]
        if lanes:
            import concurrent.futures as cf
            import multiprocessing

            if preload is not None:
                preload()  # imported once here, inherited by the forked processes
            for _ in lanes:
                # start each process now, from this thread while it is the only one: a fork from a helper
                # thread could copy a lock (the import lock) that the main thread holds at that moment
                pools.append(cf.ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"),
                                                    initializer=initializer, initargs=initargs))
                pools[-1].submit(int).result()

            def drive_lane(chain: list, pool) -> None:  # waits on its process (no CPU here), records its stages
                try:
                    for stage in chain:
                        p = self.prepare(stage)
                        if p is None:
                            continue
                        ts = time.perf_counter()
                        fut = pool.submit(_execute, stage.fn)
                        try:
                            r, el, cpu = fut.result()
                        except Exception as exc:
                            if stopping.is_set():  # interrupted: its process was stopped, no failure
                                return
                            self.failed(stage, p[1], exc, time.perf_counter() - ts)
                        else:
                            self.finished(stage, p[0], p[1], r, el, cpu)
                except BaseException as exc:  # noqa: BLE001  (re-raised in the main thread)
                    lane_error.append(exc)

            for chain, pool in zip(lanes, pools):
                helpers.append(threading.Thread(target=drive_lane, args=(chain, pool), name="flexstab-study-lane",
                                                daemon=True))
                helpers[-1].start()
        try:
            for stage in here:
                self.run_stage(stage)
            for helper in helpers:
                helper.join()
        except BaseException as exc:
            stopping.set()
            self.stop(exc, time.perf_counter() - t0)
            for pool in pools:  # interrupted: stop the other processes now, do not wait for their stages
                for proc in list(getattr(pool, "_processes", {}).values()):
                    proc.terminate()
                pool.shutdown(wait=False, cancel_futures=True)
            pools = []
            raise
        finally:
            for pool in pools:
                pool.shutdown(wait=True)
        if lane_error:
            raise lane_error[0]


def stage_section(rec: Mapping[str, Any], reused: bool = False) -> list:
    """The head of a stage's report section from its record: where its data is, its wall and CPU time (and
    that it was reused), its notes and failed checks; then its blocks."""
    head = f"Data: `{rec['json']}`; {rec['elapsed']:.1f} s" + (
        f" (CPU {rec['cpu']:.1f} s)" if isinstance(rec.get("cpu"), (int, float)) else "")
    if reused:
        head += f"; reused from the run finished at {rec['finished_at']} (inputs unchanged)"
    blocks = [text(head)]
    if rec.get("notes"):
        blocks.append(text(f"**Note:** {'; '.join(rec['notes'])}"))
    if rec.get("check_failures"):
        blocks.append(text(f"**Check failed:** {'; '.join(rec['check_failures'])}"))
    return blocks + list(rec["blocks"])


# ----------------------------------------------------------------------------- the folder lock
#: The lock file of a study's output folder: holds the pid of the study writing there.
LOCK_FILE = ".flexstab.lock"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


@contextlib.contextmanager
def folder_lock(out: Path) -> Iterator[Path]:
    """Hold ``out/.flexstab.lock`` (this process's pid) while the block runs: one study per folder.

    A lock left by a process that no longer runs (killed with SIGKILL, a crashed machine) is stale:
    it is replaced, with a log line.

    Raises
    ------
    ValueError
        Another running process holds the folder (one line naming it, its pid and the lock file).
    """
    path = Path(out) / LOCK_FILE
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid = int(path.read_text().split()[0])
            except (OSError, ValueError, IndexError):
                pid = -1
            if pid > 0 and pid != os.getpid() and _pid_alive(pid):
                raise ValueError(f"output folder {str(out)!r} is in use by another flexstab study (pid {pid}; "
                                 f"lock file {path}): wait for it to finish or choose another --out") from None
            logger.warning("removing the stale lock %s (pid %s is not running)", path, pid)
            path.unlink(missing_ok=True)
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{os.getpid()}\n")
        break
    else:  # pragma: no cover - another process took the stale lock between our two attempts
        raise ValueError(f"output folder {str(out)!r} is in use by another flexstab study (lock file {path})")
    try:
        yield path
    finally:
        try:
            if path.read_text().split()[0] == str(os.getpid()):
                path.unlink()
        except (OSError, IndexError):
            pass
