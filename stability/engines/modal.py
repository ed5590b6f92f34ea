"""The frozen-modal engine: an adapter to :func:`stability.modal.modal_floquet`."""
from __future__ import annotations

from typing import Any, Optional

from stability.engines.base import Engine, register
from stability.engines.magnus import _FLOQUET_OPTIONS

__all__ = ["ModalEngine"]


@register
class ModalEngine(Engine):
    """The exponential midpoint rule (or ``order=4, 6``) in the smooth frozen-modal frame of ``P``.

    Richardson-extrapolated from ``N, N/2, N/4`` (or ratio 3) with ``extrapolate=True``, adaptive in
    ``N`` without ``n_steps``; certified by the extrapolation's estimate and, with ``check=True``, a
    non-nested check solve.  Falls back (with a warning) to the adaptive ``magnus6`` engine in the
    model's coordinates when no smooth frame exists.  ``system`` must carry ``.period``.
    """

    name = "modal"
    options = _FLOQUET_OPTIONS | {"order", "samples", "basis", "extrapolate", "levels", "check", "collapse"}

    def run(self, system: Any, period: Optional[float], rtol: float, **options: Any) -> Any:
        from stability.modal import modal_floquet

        if period is not None and getattr(system, "period", None) is None:
            raise ValueError("modal: the system must carry its own .period")
        order = options.pop("order", 2)
        if order not in (2, 4, 6):
            raise ValueError(f"modal: order must be 2, 4 or 6, got {order!r}")
        return modal_floquet(system, method=f"magnus{order}", rtol=rtol, **options)
