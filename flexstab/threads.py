"""BLAS threads: one per process unless the user asks for more.

Every parallel path of flexstab is already parallel at the level of whole
evaluations: the study runs its Exudyn chain in a process beside the main one,
tunings and charts fan their orthogonal-array runs and grid points out to
process pools or Dask workers.  The matrices of one evaluation are small
(tens to a few hundred rows), where a multi-threaded BLAS spends more time
waking and synchronising its threads than multiplying, and two processes that
each start one BLAS thread per core oversubscribe the machine (on 2 cores the
study ran 4-8x slower than with one BLAS thread per process).

So each process limits its BLAS to :data:`DEFAULT_BLAS_THREADS` thread:

* the CLI, before any numerical work (``flexstab --blas-threads N`` or the
  environment variable :data:`ENV_VAR` override it);
* every worker of the process pools of :func:`flexstab.executor.make_executor`
  and of the study's Exudyn process, in its initialiser;
* every Dask worker reached through :class:`flexstab.executor.DaskExecutor`,
  through a worker plugin.

:func:`limit_blas_threads` sets the usual environment variables (read by a
BLAS loaded later, and inherited by every child process) and limits the BLAS
libraries already loaded through :mod:`threadpoolctl`.
"""
from __future__ import annotations

import os
from typing import Mapping, Optional, Union

__all__ = ["DEFAULT_BLAS_THREADS", "ENV_VAR", "BLAS_ENV_VARS", "blas_threads", "limit_blas_threads"]

#: BLAS threads per process unless overridden (see the module docstring for the reason).
DEFAULT_BLAS_THREADS = 1
#: Environment variable overriding :data:`DEFAULT_BLAS_THREADS` (``--blas-threads`` overrides it).
ENV_VAR = "FLEXSTAB_BLAS_THREADS"
#: Thread-count variables of the BLAS / OpenMP runtimes numpy and scipy may load.
BLAS_ENV_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
                 "VECLIB_MAXIMUM_THREADS")


def _positive_int(value: Union[str, int], where: str) -> int:
    try:
        n = int(str(value).strip())
    except ValueError:
        raise ValueError(f"{where} must be a positive integer, got {value!r}") from None
    if n < 1:
        raise ValueError(f"{where} must be a positive integer, got {value!r}")
    return n


def blas_threads(value: Optional[Union[str, int]] = None, environ: Optional[Mapping[str, str]] = None) -> int:
    """The BLAS threads per process: ``value`` if given, else ``$FLEXSTAB_BLAS_THREADS``, else 1.

    ``OPENBLAS_NUM_THREADS`` and its relatives are not read: they are often set machine-wide (to
    the number of cores, by a batch scheduler) for programs that are parallel only inside BLAS.

    Raises
    ------
    ValueError
        The value (or the environment variable) is not a positive integer.
    """
    env = os.environ if environ is None else environ
    if value is not None:
        return _positive_int(value, "--blas-threads")
    text = env.get(ENV_VAR)
    if text is not None and text.strip():
        return _positive_int(text, ENV_VAR)
    return DEFAULT_BLAS_THREADS


def limit_blas_threads(n: Optional[int] = None) -> int:
    """Limit this process (and the processes it starts) to ``n`` BLAS threads; return ``n``.

    ``n`` defaults to :func:`blas_threads`.  Sets :data:`ENV_VAR` and :data:`BLAS_ENV_VARS` in
    ``os.environ`` (a BLAS loaded later reads them; child processes inherit them) and limits the
    BLAS libraries already loaded with :func:`threadpoolctl.threadpool_limits`.
    """
    n = blas_threads() if n is None else _positive_int(n, "the number of BLAS threads")
    os.environ[ENV_VAR] = str(n)
    for var in BLAS_ENV_VARS:
        os.environ[var] = str(n)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=n, user_api="blas")
    return n
