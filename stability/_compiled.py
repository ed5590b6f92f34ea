"""Compiled kernel (numba) for the batched Magnus-6 solves of small systems.

:func:`stability.floquet` solves a small system (``n <= SMALL_N``) at three step
counts in one batch.  On 4x4 matrices the numpy stacks of that batch
(:func:`stability.magnus.magnus_exponents_soa`, :func:`stability.expm.expm_soa`,
the level products) spend about as long in per-call overhead and temporaries
as in arithmetic; this kernel does the same steps in one compiled call, with
the loops over the stack innermost (contiguous, vectorised by LLVM):

* the Magnus-6 exponent of every sub-interval from ``P`` at its three Gauss
  nodes (Blanes, Casas, Oteo & Ros 2009, Eq. 257: the rows of
  ``stability.magnus._MAGNUS6_ROWS``), and its commutator part;
* the degree-16 Taylor exponential, Paterson-Stockmeyer, with scaling and
  squaring.  The scaling comes from ``alpha_3 = max(||A^3||^(1/3), ||A^4||^(1/4))``
  (Al-Mohy & Higham 2009, Thm 4.2) of the largest member *of each level*
  (the numpy path takes one scaling for the whole batch, that of the coarsest
  level; the finer levels here square fewer times: the same bound, less work);
* the ordered product ``E_N ... E_1`` of each level (sequential; the numpy path
  pairs: the same products in another rounding order).

Used when ``numba`` can be imported (it is a dependency of the package) and the
environment variable ``FLEXSTAB_NUMBA`` is not ``0``, once a process has run
:data:`COMPILED_AFTER` small-system batches (a short command stays on numpy and
does not pay for importing numba); otherwise, and for the other schemes, the
numpy path runs (same method, same accuracy; the test suite checks both).  The
machine code is compiled on first use (10-25 s) and cached on disk by numba
(``stability._magnus_kernel``).
"""
from __future__ import annotations

import itertools
import logging
import math
import os
from typing import Any, Optional

import numpy as np

__all__ = ["available", "magnus6_levels"]

logger = logging.getLogger(__name__)


def _enabled() -> bool:
    return os.environ.get("FLEXSTAB_NUMBA", "1").strip().lower() not in ("0", "false", "no", "off")


#: Small-system batches a process runs on the numpy path before it loads the kernel: importing numba
#: and loading the cached kernel cost ~0.4 s, which the kernel wins back (~0.1 ms a batch on the
#: reduced model) only after some thousands of batches.  A command that evaluates a few hundred
#: multipliers (a pool worker of a Taguchi array) stays on numpy; a long loop (a chart, a tuning
#: run, a benchmark) switches.  :func:`available` loads the kernel at once.
COMPILED_AFTER = 2000

_state: dict[str, Any] = {"batches": 0}


def _kernel() -> Optional[Any]:
    """The compiled kernel, or None (numba missing or disabled, or the kernel failing to compile)."""
    if "kernel" not in _state:
        kernel = None
        if _enabled():
            try:
                from stability._magnus_kernel import levels

                # compile (or load from the cache) on a tiny problem, once per process
                levels(np.zeros((3, 1, 1, 1)), np.ones(1), np.array([0, 1], dtype=np.int64),
                       np.empty((1, 1, 1)), np.empty((1, 3)))
                kernel = levels
            except ImportError as exc:  # numba not installed: the numpy path
                logger.debug("compiled Magnus kernel unavailable: %s", exc)
            except Exception as exc:  # pragma: no cover - a broken numba installation
                logger.warning("compiled Magnus kernel failed to compile, using numpy: %s", exc)
        _state["kernel"] = kernel
    return _state["kernel"]


def available() -> bool:
    """Whether the compiled kernel runs (loads it, compiling on the first use of an installation)."""
    return _kernel() is not None


def batch(Pg: np.ndarray, h: np.ndarray, Ns: list[int]) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """:func:`magnus6_levels` once the process has run :data:`COMPILED_AFTER` batches (or loaded the
    kernel otherwise); None before (the caller's numpy path)."""
    if "kernel" not in _state:
        _state["batches"] += 1
        if _state["batches"] <= COMPILED_AFTER:
            return None
    return magnus6_levels(Pg, h, Ns)


def magnus6_levels(Pg: np.ndarray, h: np.ndarray, Ns: list[int]) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """Magnus-6 level products of a matrix-major batch by the compiled kernel.

    Parameters
    ----------
    Pg : ndarray, shape (3, n, n, sum(Ns))
        ``P`` at the three Gauss nodes of every sub-interval, the levels one after another.
    h : ndarray, shape (sum(Ns),)
        Step length of every sub-interval.
    Ns : list of int
        Sub-intervals of each level.

    Returns
    -------
    (phis, stats) or None
        ``phis`` ``(L, n, n)`` the products ``E_N ... E_1`` of each level; ``stats`` ``(L, 3)``:
        ``sum_k tr Omega_k``, ``max_k ||Omega_k - h Pbar_k||_1``, ``max_k ||Omega_k||_1``.
        None when the kernel is not available.
    """
    kernel = _kernel()
    if kernel is None:
        return None
    n = Pg.shape[1]
    bounds = np.array([0, *itertools.accumulate(Ns)], dtype=np.int64)  # (np.cumsum costs more on a short list)
    phis = np.empty((len(Ns), n, n))
    stats = np.empty((len(Ns), 3))
    # writable C arrays only (a read-only one, such as the cached step lengths, is another numba type:
    # a second compilation)
    kernel(np.require(Pg, np.float64, ["C", "W"]), np.require(h, np.float64, ["C", "W"]), bounds, phis, stats)
    return phis, stats
