"""The ``flexstab`` command-line tool.

Every sub-command lives in :mod:`flexstab.commands`.  Invalid input ends
with one line on stderr and exit code 2; a computation that cannot be
completed (an orbit that does not converge, an Exudyn solver failure) with
one line and exit code 1; never a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import Optional, Sequence

__all__ = ["main", "build_parser", "COMMANDS"]

#: Sub-command modules, in the order ``--help`` lists them.
COMMANDS = ("floquet", "modes", "tune", "validate", "chart", "campbell", "study")


class CLIError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (``prog: error: ...``), exit code 2."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="flexstab",
        description="Floquet stability analysis and Taguchi-tuned PD control of a flexible manipulator.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
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


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
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
    except KeyboardInterrupt:
        print(f"flexstab {args.command}: interrupted", file=sys.stderr)
        return 130


def _is_linear_algebra_error(exc: BaseException) -> bool:
    """Whether ``exc`` is numpy's ``LinAlgError`` (a ``ValueError`` subclass raised by a computation)."""
    numpy = sys.modules.get("numpy")
    return numpy is not None and isinstance(exc, numpy.linalg.LinAlgError)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
