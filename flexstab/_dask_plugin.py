"""The Dask worker plugin of :class:`flexstab.executor.DaskExecutor` (imported only with Dask)."""
from __future__ import annotations

from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from flexstab.threads import limit_blas_threads

__all__ = ["BlasThreadsPlugin"]


class BlasThreadsPlugin(WorkerPlugin):
    """Limit each Dask worker process to ``n`` BLAS threads (:mod:`flexstab.threads`).

    Registered with ``Client.register_plugin``: :meth:`setup` runs on every worker connected now
    and on every worker that joins later.
    """

    def __init__(self, n: int) -> None:
        self.n = int(n)

    def setup(self, worker: Any) -> None:  # noqa: ARG002 - the plugin protocol's signature
        limit_blas_threads(self.n)

    def __repr__(self) -> str:
        return f"BlasThreadsPlugin(n={self.n})"
