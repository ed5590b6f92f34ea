"""The ``flexstab`` command-line tool.

Every sub-command lives in :mod:`flexstab.commands`.  Invalid input ends
with one line on stderr and exit code 2; a computation that cannot be
completed (an orbit that does not converge, an Exudyn solver failure) or a
check that failed with one line and exit code 1; never a traceback.  Exit
code 0 means every check passed.

Building the parser imports no numerical package (the command modules import
numpy, scipy and Exudyn inside their ``run``), so a mistyped option is
reported at once.  Each process runs one BLAS thread unless ``--blas-threads``
or ``$FLEXSTAB_BLAS_THREADS`` says otherwise (:mod:`flexstab.threads`),
applied before any numerical work.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import logging
import os
import re
import sys
from typing import Optional, Sequence

__all__ = ["main", "build_parser", "COMMANDS"]

#: Sub-command modules, in the order ``--help`` lists them.
COMMANDS = ("floquet", "modes", "tune", "validate", "chart", "campbell", "study")


class CLIError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


#: What ``argparse`` takes for a negative number (a value, not an option): also multiples of pi
#: (``--omega -2pi``), so that such a value reaches its own check and gets its own message.
NEGATIVE_NUMBER = re.compile(r"^-(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?:\s*\*?\s*pi)?|pi|inf|nan)$",
                             re.IGNORECASE)


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (``prog: error: ...``), exit code 2, and
    that reads ``-2pi`` or ``-1e3`` as a (negative) value."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _blas_threads_type(text: str) -> int:
    from flexstab.threads import blas_threads

    try:
        return blas_threads(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="flexstab",
        description="Floquet stability analysis and Taguchi-tuned PD control of a flexible manipulator.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    parser.add_argument("--blas-threads", type=_blas_threads_type, default=None, metavar="N",
                        help="BLAS threads per process (default 1, or $FLEXSTAB_BLAS_THREADS): the parallel "
                             "work runs in whole evaluations per process, see docs/running.md")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"flexstab.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"flexstab.commands.{name}":
                continue  # sub-command not available in this build
            raise
        module.register(sub)
    return parser


def _terminate(signum, frame):  # noqa: ARG001 - the signal handler's signature
    """SIGTERM as Ctrl-C: the study records ``"status": "interrupted"`` and the command ends with one line."""
    raise KeyboardInterrupt("SIGTERM")


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        previous_sigterm = signal.signal(signal.SIGTERM, _terminate)
    else:  # pragma: no cover - signal handlers can be set in the main thread only
        previous_sigterm = None
    try:
        return _run(args)
    finally:
        if previous_sigterm is not None:
            signal.signal(signal.SIGTERM, previous_sigterm)


def _one_line_warnings(command: str):
    """A ``warnings.formatwarning`` giving ``flexstab CMD: warning: MESSAGE`` (one line, no source path
    or code line): the library warns through :mod:`warnings`, the command line reports it.  Only the
    format is replaced, so a caller recording warnings (``warnings.catch_warnings(record=True)``)
    still receives them."""

    def format_warning(message, category, filename, lineno, line=None) -> str:
        text = " ".join(str(message).split())
        return f"flexstab {command}: warning: {text}\n"

    return format_warning


def _run(args: argparse.Namespace) -> int:
    import warnings

    previous_format = warnings.formatwarning
    warnings.formatwarning = _one_line_warnings(args.command)
    try:
        return _run_command(args)
    finally:
        warnings.formatwarning = previous_format


def _run_command(args: argparse.Namespace) -> int:
    try:
        from flexstab.threads import blas_threads, limit_blas_threads

        limit_blas_threads(blas_threads(args.blas_threads))  # before any numerical work (docs/running.md)
        # stdout is the command's result only (flexstab.options.result_output): whatever else is printed
        # while it runs -- Exudyn's solver banners and warnings -- goes to stderr with -v, else nowhere
        # (a failure is reported by its own one line)
        args.result_stdout = sys.stdout
        with contextlib.redirect_stdout(sys.stderr if args.verbose else io.StringIO()):
            rc = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, inside the handler, not at interpreter exit
        return rc
    except BrokenPipeError:
        # the reader went away (``flexstab tune | head``): not an error of ours; stop quietly.
        # Point stdout at devnull so that the interpreter's final flush does not raise again.
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return 141  # 128 + SIGPIPE, as a shell reports a process killed by the signal
    except (ValueError, CLIError, OSError) as exc:
        if not _is_linear_algebra_error(exc):
            print(f"flexstab {args.command}: error: {exc}", file=sys.stderr)
            return 2
        # numpy's LinAlgError is a ValueError, but a singular matrix inside a computation is a
        # numerical failure (exit 1), never bad input
        print(f"flexstab {args.command}: failed: {type(exc).__name__}: {str(exc).strip() or 'singular matrix'}",
              file=sys.stderr)
        return 1
    except (RuntimeError, FloatingPointError, ArithmeticError) as exc:
        # a computation that could not be completed (an orbit that does not converge,
        # an Exudyn solver failure): one line naming the cause, exit code 1
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"flexstab {args.command}: failed: {type(exc).__name__}: {first}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        term = str(exc) == "SIGTERM"
        print(f"flexstab {args.command}: interrupted{' (SIGTERM)' if term else ''}", file=sys.stderr)
        return 143 if term else 130  # 128 + the signal number, as a shell reports it


def _is_linear_algebra_error(exc: BaseException) -> bool:
    """Whether ``exc`` is numpy's ``LinAlgError`` (a ``ValueError`` subclass raised by a computation)."""
    numpy = sys.modules.get("numpy")
    return numpy is not None and isinstance(exc, numpy.linalg.LinAlgError)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
