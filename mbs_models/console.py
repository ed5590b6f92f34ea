"""Exudyn's console output (solver banners) silenced around a block."""
from __future__ import annotations

import contextlib
from typing import Iterator

__all__ = ["exudyn_console"]


@contextlib.contextmanager
def exudyn_console(quiet: bool) -> Iterator[None]:
    """Silence Exudyn's console output (solver banners) while the block runs.

    Uses ``exudyn.config.printToConsole`` and restores the caller's value; ``quiet=False``
    leaves it alone.
    """
    if not quiet:
        yield
        return
    import exudyn as exu

    previous = bool(exu.config.printToConsole)
    exu.config.printToConsole = False
    try:
        yield
    finally:
        exu.config.printToConsole = previous
