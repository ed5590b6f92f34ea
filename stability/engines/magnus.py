"""The Magnus engines and the paper's procedure: adapters to :func:`stability.floquet.floquet`."""
from __future__ import annotations

from typing import Any, Optional

from stability.engines.base import Engine, register

__all__ = ["MagnusEngine", "PaperEngine"]

#: Options of :func:`stability.floquet.floquet` a Magnus engine passes through.
_FLOQUET_OPTIONS = frozenset({"n_steps", "stability_tol", "error_estimate", "max_steps", "balance", "accuracy",
                              "small_multipliers", "expm_blocks"})


@register
class MagnusEngine(Engine):
    """Magnus propagators of order 6 (default), 4 or 2 (``order=``) in the model's coordinates.

    Adaptive unless ``n_steps`` is given: steps refined until the Richardson estimate of the moduli
    (``accuracy="moduli"``), the multipliers or the dominant ones meets ``rtol``.  Certified by that
    estimate, ``reliable_digits`` and the Liouville residual (:mod:`stability.floquet`).
    """

    name = "magnus"
    options = _FLOQUET_OPTIONS | {"order"}

    def run(self, system: Any, period: Optional[float], rtol: float, **options: Any) -> Any:
        from stability.floquet import floquet

        order = options.pop("order", 6)
        if order not in (2, 4, 6):
            raise ValueError(f"magnus: order must be 2, 4 or 6, got {order!r}")
        return floquet(system, period, method=f"magnus{order}", rtol=rtol, **options)


@register
class PaperEngine(Engine):
    """The paper's procedure: ``n`` integrations from the unit vectors with ``solve_ivp`` (DOP853, Radau
    when ``P`` is stiff).  The independent reference; never chosen by the rule."""

    name = "paper"
    options = frozenset({"stability_tol", "reference", "small_multipliers", "error_estimate"})

    def run(self, system: Any, period: Optional[float], rtol: float, **options: Any) -> Any:
        from stability.floquet import floquet

        return floquet(system, period, method="paper", rtol=rtol, **options)
