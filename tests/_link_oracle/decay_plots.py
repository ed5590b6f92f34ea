"""Figures of the nonlinear validation: nonlinear runs against the linear prediction.

:func:`plot_validation_figure` draws one column per
:class:`~_link_oracle.closed_loop.ValidationResult` with three rows:

1. the hub-angle error ``Delta q_a(t)`` of the nonlinear run (perturbed minus
   reference), the response of the linearised Exudyn system to the same
   initial perturbation (:func:`~_link_oracle.closed_loop.linear_prediction`) and
   the envelope ``+- C |rho|^(t/T)``;
2. ``|Delta q_a|`` on a log scale with the stroboscopic samples ``|Delta q_a(kT)|``
   of both and the envelope (the per-period ratio is the slope);
3. the tip-deflection error of both runs.

The linear curves are clipped to the range of the nonlinear data where they
explode (unstable loops leave the linear range).
"""
from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from _link_oracle.closed_loop import LinearPrediction, ValidationResult, linear_prediction

__all__ = ["plot_validation_figure"]

logger = logging.getLogger(__name__)


def _fmt(x: float) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.4g}"


def plot_validation_figure(
    results: Sequence[ValidationResult],
    path: Union[str, Path],
    *,
    titles: Optional[Sequence[str]] = None,
    predictions: Optional[Sequence[Optional[LinearPrediction]]] = None,
    suptitle: Optional[str] = None,
) -> Path:
    """Write a PNG comparing nonlinear runs with their linear predictions.

    Parameters
    ----------
    results : sequence of ValidationResult
        One column each.
    path : str or Path
        Output PNG.
    titles : sequence of str, optional
        Column titles (default: the gains).
    predictions : sequence of LinearPrediction or None, optional
        Default: :func:`~_link_oracle.closed_loop.linear_prediction` of each result.
    suptitle : str, optional

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = list(results)
    if not results:
        raise ValueError("no results to plot")
    if predictions is None:
        predictions = [linear_prediction(r) if (r.prediction is not None or r.exudyn is not None) else None
                       for r in results]
    titles = list(titles) if titles is not None else [f"kp = {r.kp:.4g}, kd = {r.kd:.4g}" for r in results]
    ncol = len(results)
    fig, axes = plt.subplots(3, ncol, figsize=(4.6 * ncol, 9.6), squeeze=False, sharex="col", layout="constrained")
    for j, (r, lp, title) in enumerate(zip(results, predictions, titles)):
        T = r.period
        ax_h, ax_l, ax_t = axes[0, j], axes[1, j], axes[2, j]
        t = r.times
        ylim_h = 1.15 * float(np.max(np.abs(r.hub_error))) if r.hub_error.size else 1.0
        ylim_t = 1.15 * float(np.max(np.abs(r.tip_error))) if r.tip_error.size else 1.0
        ax_h.plot(t / T, r.hub_error, color="C0", lw=1.0, label="nonlinear (Exudyn)")
        ax_t.plot(t / T, 1e3 * r.tip_error, color="C0", lw=1.0, label="nonlinear (Exudyn)")
        if r.hub_error.size:
            pos = np.abs(r.hub_error) > 0
            ax_l.semilogy(t[pos] / T, np.abs(r.hub_error[pos]), color="C0", lw=0.8, label="|nonlinear|")
        k = np.arange(r.stroboscopic.size)
        ok = r.stroboscopic > 0
        ax_l.semilogy(k[ok], r.stroboscopic[ok], "o", color="C0", ms=5, label="nonlinear at t = kT")
        if lp is not None:
            tl = lp.t / T
            ax_h.plot(tl, lp.hub_error, "--", color="C1", lw=1.0, label="linearised Exudyn")
            ax_t.plot(tl, 1e3 * lp.tip_error, "--", color="C1", lw=1.0, label="linearised Exudyn")
            env = lp.envelope(lp.t)
            if math.isfinite(lp.envelope_constant):
                ax_h.plot(tl, env, ":", color="C3", lw=1.2, label=rf"$\pm C|\rho|^{{t/T}}$, |ρ| = {lp.modulus:.4g}")
                ax_h.plot(tl, -env, ":", color="C3", lw=1.2)
                ax_l.semilogy(tl, env, ":", color="C3", lw=1.2, label=r"$C|\rho|^{t/T}$")
            kl = np.arange(lp.stroboscopic.size)
            okl = lp.stroboscopic > 0
            ax_l.semilogy(kl[okl], lp.stroboscopic[okl], "x", color="C1", ms=7, label="linear at t = kT")
        ax_h.set_ylim(-ylim_h, ylim_h)
        ax_t.set_ylim(-1e3 * ylim_t, 1e3 * ylim_t)
        if r.hub_error.size:
            pos_vals = np.abs(r.hub_error)[np.abs(r.hub_error) > 0]
            if pos_vals.size:
                lo = max(float(np.min(r.stroboscopic[ok])) if np.any(ok) else float(pos_vals.min()), 1e-12)
                ax_l.set_ylim(lo / 30.0, 3.0 * float(pos_vals.max()))
        if r.linear_range_left_at is not None:
            for ax in (ax_h, ax_l, ax_t):
                ax.axvline(r.linear_range_left_at / T, color="0.5", lw=0.8, ls="-.")
            ax_h.text(r.linear_range_left_at / T, 0.9 * ylim_h, " linear range left", fontsize=8, color="0.3", va="top")
        if r.diverged and r.diverged_at is not None:
            ax_h.axvline(r.diverged_at / T, color="r", lw=0.8)
        sub = (
            f"measured {_fmt(r.measured_ratio_per_period)} / period; "
            f"Exudyn lin. {_fmt(r.predicted_multiplier_exudyn)}, reduced {_fmt(r.predicted_multiplier_reduced)}"
        )
        ax_h.set_title(f"{title}\n{sub}", fontsize=9)
        ax_h.set_ylabel(r"hub-angle error $\Delta q_a$ (rad)")
        ax_l.set_ylabel(r"$|\Delta q_a|$ (rad)")
        ax_t.set_ylabel(r"tip-deflection error (mm)")
        ax_t.set_xlabel("time t / T (periods)")
        for ax in (ax_h, ax_l, ax_t):
            ax.grid(True, alpha=0.3)
            ax.set_xlim(0, max(r.periods, 1))
        if j == 0:
            ax_h.legend(fontsize=8, loc="lower right")
            ax_l.legend(fontsize=8, loc="lower left")
            ax_t.legend(fontsize=8, loc="lower right")
        elif lp is not None and math.isfinite(lp.envelope_constant):
            ax_h.legend(handles=ax_h.lines[2:3], fontsize=8, loc="lower right")
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    logger.info("wrote %s", path)
    return path
