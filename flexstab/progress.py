"""Progress of long commands: tqdm bars on a terminal, one line per step otherwise (stderr).

Library functions take ``progress`` as ``False`` (silent), ``True`` (a tqdm bar) or a *bar factory*:
a callable ``factory(total=..., desc=..., unit=...)`` returning an object with tqdm's ``update(n)``,
``set_postfix_str(s)`` and ``close()`` (and usable as a context manager).  :func:`progress_bars` is
the command line's rule: tqdm on a terminal, :class:`LineProgress` on a pipe or a file.  Steps that a
library reports through :mod:`logging` (the nonlinear validation's stages) are shown as lines by
:func:`progress_log`.
"""
from __future__ import annotations

import contextlib
import functools
import logging
import sys
import time
from typing import Any, Callable, Iterator, Optional, TextIO

__all__ = ["LineProgress", "MIN_INTERVAL", "progress_bars", "make_bar", "progress_log"]

#: Seconds between two lines of a :class:`LineProgress` (its first line, too, comes only after this
#: long: a step that ends sooner prints nothing, so quick runs and one-line errors stay one line).
MIN_INTERVAL = 5.0


class LineProgress:
    """A tqdm-like bar that writes one line per step (``update``) to ``stream``, at most one line every
    ``min_interval`` seconds, and a last line on ``close`` if it wrote any.

    A line reads ``desc: n/total unit (p %), t s[, postfix]``.
    """

    def __init__(self, total: Optional[int] = None, desc: Optional[str] = None, unit: str = "it",
                 stream: Optional[TextIO] = None, min_interval: float = MIN_INTERVAL, clock: Callable[[], float]
                 = time.monotonic, **_tqdm_options: Any) -> None:
        self.total, self.desc, self.unit = total, desc or "progress", unit
        self.stream = stream if stream is not None else sys.stderr
        self.min_interval, self.clock = float(min_interval), clock
        self.n, self.postfix = 0, ""
        self.start = self.last = clock()
        self.lines = 0
        self.written = -1  # the count of the last line written
        self.closed = False

    def _line(self) -> str:
        done = f"{self.n}/{self.total}" if self.total else f"{self.n}"
        pct = f" ({100.0 * self.n / self.total:.0f} %)" if self.total else ""
        post = f", {self.postfix}" if self.postfix else ""
        return f"{self.desc}: {done} {self.unit}{pct}, {self.clock() - self.start:.1f} s{post}"

    def _write(self) -> None:
        print(self._line(), file=self.stream, flush=True)
        self.lines += 1
        self.last = self.clock()
        self.written = self.n

    def update(self, n: int = 1) -> None:
        """Count ``n`` more steps; write a line if ``min_interval`` has passed since the last one."""
        self.n += int(n)
        if self.clock() - self.last >= self.min_interval:
            self._write()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:  # noqa: ARG002 - tqdm's signature
        self.postfix = str(s)

    def close(self) -> None:
        """Write the last line (if any line was written before and the count moved since), once."""
        if not self.closed and self.lines and self.written != self.n:
            self._write()
        self.closed = True

    def __enter__(self) -> "LineProgress":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def progress_bars(stream: Optional[TextIO] = None) -> Callable[..., Any]:
    """The command line's progress rule: a factory of tqdm bars if ``stream`` (stderr) is a terminal,
    else of :class:`LineProgress` writing to it."""
    stream = stream if stream is not None else sys.stderr
    if getattr(stream, "isatty", lambda: False)():
        from tqdm.auto import tqdm

        return functools.partial(tqdm, leave=False, file=stream)
    return functools.partial(LineProgress, stream=stream)


def make_bar(progress: Any, *, total: Optional[int], desc: Optional[str], unit: str = "it") -> Any:
    """A bar for ``progress`` (``False``/``None``: a disabled tqdm bar, ``True``: tqdm, a factory: its bar)."""
    if callable(progress):
        return progress(total=total, desc=desc, unit=unit)
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=not progress, leave=False)


class _LineHandler(logging.Handler):
    def __init__(self, prefix: str, stream: TextIO) -> None:
        super().__init__(logging.INFO)
        self.prefix, self.stream = prefix, stream

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno >= logging.WARNING:  # warnings go where they would go without this handler
            logging.getLogger().handle(record)
            return
        try:
            print(f"{self.prefix}: {record.getMessage()}", file=self.stream, flush=True)
        except Exception:  # noqa: BLE001 - logging's rule: a handler never raises
            self.handleError(record)


@contextlib.contextmanager
def progress_log(logger_name: str, prefix: str, stream: Optional[TextIO] = None) -> Iterator[None]:
    """While the block runs, show the INFO records of ``logger_name`` (a library's step reports) as
    ``prefix: message`` lines on ``stream`` (stderr), and only there; the logger's level and
    propagation are restored afterwards.  Nothing is added if the logger shows INFO already (``-v``)."""
    log = logging.getLogger(logger_name)
    if log.isEnabledFor(logging.INFO):
        yield
        return
    handler = _LineHandler(prefix, stream if stream is not None else sys.stderr)
    level, propagate = log.level, log.propagate
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False  # the root handler (WARNING and up) would print them a second time
    try:
        yield
    finally:
        log.removeHandler(handler)
        log.setLevel(level)
        log.propagate = propagate
