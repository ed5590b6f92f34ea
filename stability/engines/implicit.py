"""The implicit engine: an adapter to :func:`stability.implicit.implicit_floquet`."""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from stability.engines.base import Engine, FloquetSolution, register

__all__ = ["ImplicitEngine"]


@register
class ImplicitEngine(Engine):
    """The ``k`` largest multipliers by ARPACK on the matrix-free one-period map (``k``, ``n_steps``,
    ``order`` 2/4/6 of the Magnus factors).  Certified per Ritz pair by its residual (``certified``)
    and by the ``N`` vs ``N/2`` estimate; only certified multipliers are returned.  Never chosen by the
    rule (it gives the largest moduli, not the whole spectrum)."""

    name = "implicit"
    options = frozenset({"k", "n_steps", "order", "error_estimate", "balance", "seed"})
    complete = False

    def run(self, system: Any, period: Optional[float], rtol: float, **options: Any) -> Any:
        from stability.implicit import implicit_floquet

        order = options.pop("order", 2)
        if order not in (2, 4, 6):
            raise ValueError(f"implicit: order must be 2, 4 or 6, got {order!r}")
        return implicit_floquet(system, period, method=f"magnus{order}", **options)

    def solution(self, result: Any) -> FloquetSolution:
        mult = np.asarray(result.multipliers)[np.asarray(result.certified, dtype=bool)]
        return FloquetSolution(multipliers=mult, spectral_radius=float(result.spectral_radius),
                               error_estimate=float(result.error_estimate), complete=False, method=self.name,
                               period=float(result.period), detail=result)
