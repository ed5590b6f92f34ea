"""Figures of the nonlinear validation: measured against predicted multipliers.

:func:`plot_multiplier_plane` draws the multipliers measured from nonlinear Exudyn runs
(:class:`~validation.multipliers.MultiplierValidation`) beside the prediction in the complex plane.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Optional, Sequence, Union

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from validation.multipliers import MultiplierValidation

__all__ = ["plot_multiplier_plane"]

logger = logging.getLogger(__name__)


def plot_multiplier_plane(
    results: Sequence["MultiplierValidation"],
    path: Union[str, Path],
    *,
    titles: Optional[Sequence[str]] = None,
    suptitle: Optional[str] = None,
) -> Path:
    """Measured and predicted multipliers in the complex plane with the unit circle.

    One column per :class:`~validation.multipliers.MultiplierValidation`:
    top, the whole plane (unit circle, every predicted multiplier, the
    compared ones, the measured ones, the alternatives); middle, the dominant
    compared multiplier with the alternative predictions (whose distance the
    measurement resolves or not); bottom, the measurement's step convergence:
    the values per step (``h, h/2, h/4``, one marker each, named in the
    legend), the extrapolated value and its error-bar circle.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    results = list(results)
    if not results:
        raise ValueError("no results to plot")
    titles = list(titles) if titles is not None else [f"{r.info.get('model', '')}: kp = {r.info.get('kp')}, kd = {r.info.get('kd')}"
                                                      for r in results]
    ncol = len(results)
    fig, axes = plt.subplots(3, ncol, figsize=(5.6 * ncol, 16.0), squeeze=False, layout="constrained")
    markers = ["^", "v", "s", "D"]
    step_markers = ["s", "D", "P", "*", "h"]

    def legend_below(a) -> None:  # below the panel (one column), not over the unit circle or the points
        a.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=1)

    def square(a, pts, floor: float) -> None:
        pts_a = np.asarray(pts)
        cx = float(np.mean([pts_a.real.min(), pts_a.real.max()]))
        cy = float(np.mean([pts_a.imag.min(), pts_a.imag.max()]))
        half = 0.6 * max(float(np.ptp(pts_a.real)), float(np.ptp(pts_a.imag)), floor)
        a.set_xlim(cx - half, cx + half)
        a.set_ylim(cy - half, cy + half)
        a.set_aspect("equal")
        a.ticklabel_format(useOffset=False, style="plain")
        a.tick_params(labelsize=8)
        a.xaxis.set_major_locator(plt.MaxNLocator(3))
        a.yaxis.set_major_locator(plt.MaxNLocator(5))
        a.set_xlabel("Re ρ")
        a.set_ylabel("Im ρ")
        a.grid(True, alpha=0.3)

    for j, (r, title) in enumerate(zip(results, titles)):
        ax, az, ah = axes[0, j], axes[1, j], axes[2, j]
        th = np.linspace(0, 2 * np.pi, 400)
        ax.plot(np.cos(th), np.sin(th), color="0.6", lw=0.8, label="unit circle")
        allm = r.prediction.all_multipliers
        allm = allm[np.abs(allm) <= 1.5 * max(1.0, float(np.max(np.abs(r.prediction.multipliers))))]
        ax.plot(allm.real, allm.imag, ".", color="0.75", ms=4, label="predicted, not compared")
        p = r.prediction.multipliers
        ax.plot(p.real, p.imag, "x", color="C1", ms=9, mew=2, label="predicted (under test)")
        if r.measured.size:
            ax.plot(r.measured.real, r.measured.imag, "o", mfc="none", color="C0", ms=10, mew=1.5,
                    label="measured (nonlinear Exudyn)")
        for i, alt in enumerate(r.alternatives):
            a = np.asarray(alt.multipliers)
            ax.plot(a.real, a.imag, markers[i % 4], mfc="none", color=f"C{i + 2}", ms=7, label=alt.name)
        lim = max(1.1, 1.1 * float(np.max(np.abs(p))))
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.axhline(0, color="0.85", lw=0.5)
        ax.axvline(0, color="0.85", lw=0.5)
        if r.diverged:
            verdict = "diverged"
        elif r.agrees and not r.agrees_all:
            verdict = "agrees (resolved multipliers); a smaller one not resolved in h"
        elif r.agrees:
            verdict = "agrees"
        elif r.measured.size and not r.step_converged:
            verdict = "no verdict: step refinement not converging"
        else:
            verdict = "DISAGREES"
        ax.set_title(f"{title}\n{r.prediction.name}: {verdict}", fontsize=9)
        ax.set_xlabel("Re ρ")
        ax.set_ylabel("Im ρ")
        legend_below(ax)
        # middle: the dominant compared multiplier against the alternative predictions
        i0 = 0
        z0 = p[i0]
        label0 = r.prediction.labels[i0] or "dominant"
        pts = [z0]
        if r.measured.size:
            m = r.measured[i0]
            bar = float(r.errors[i0])
            az.plot(m.real, m.imag, "o", mfc="none", color="C0", ms=10, mew=1.5, label=f"measured ± {bar:.2g}")
            pts += [m]
        az.plot(z0.real, z0.imag, "x", color="C1", ms=10, mew=2, label="predicted (under test)")
        for i, alt in enumerate(r.alternatives):
            a = np.asarray(alt.multipliers)
            if a.size:
                za = a[int(np.argmin(np.abs(a - z0)))]
                az.plot(za.real, za.imag, markers[i % 4], mfc="none", color=f"C{i + 2}", ms=8,
                        label=f"{alt.name} ({'consistent' if alt.consistent else 'excluded'})")
                pts.append(za)
        square(az, pts, 1e-7 * max(abs(z0), 1e-3))
        az.set_title(f"ρ = {z0.real:.5g}{z0.imag:+.5g}i ({label0}) and the alternative predictions", fontsize=9)
        legend_below(az)
        # bottom: the measurement's step convergence (one marker per step level, named in the legend: text
        # labels at the points overprinted each other) with its error-bar circle
        pts = [z0]
        if r.levels.size:
            lv = r.levels[:, i0]
            ah.plot(lv.real, lv.imag, "-", color="C0", lw=0.8, alpha=0.6)
            for n, (h, z) in enumerate(zip(r.config.steps, lv)):
                ah.plot(z.real, z.imag, step_markers[n % len(step_markers)], color="C0", ms=7, alpha=0.7,
                        label=f"measured with step h = {h:g} s")
            pts += list(lv)
        if r.measured.size:
            m = r.measured[i0]
            bar = float(r.errors[i0])
            ah.plot(m.real, m.imag, "o", mfc="none", color="C3", ms=10, mew=1.5, label="extrapolated measurement")
            ah.add_patch(Circle((m.real, m.imag), bar, fill=False, ls="--", color="C3", lw=1.0,
                                label=f"its error bar ({bar:.2g})"))
            pts += [m + bar, m - bar, m + 1j * bar, m - 1j * bar]
        ah.plot(z0.real, z0.imag, "x", color="C1", ms=10, mew=2, label="predicted (under test)")
        square(ah, pts, 1e-9 * max(abs(z0), 1e-3))
        ah.set_title(f"step convergence of the measured {label0} multiplier", fontsize=9)
        legend_below(ah)
    if suptitle:
        fig.suptitle(suptitle, fontsize=11)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    logger.info("wrote %s", path)
    return path
