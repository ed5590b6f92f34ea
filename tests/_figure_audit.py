"""Layout defects of a matplotlib figure, measured on the drawn figure (not on the PNG's pixels).

:func:`audit` draws the figure and records every text artist that is actually drawn (titles, axis and
tick labels, legend entries, annotations, figure texts) with its window extent, then reports:

* ``outside``  -- a text whose box leaves the figure (clipped title or label);
* ``small``    -- a text smaller than ``min_points`` (unreadable footnotes, 6-pt legends);
* ``overlap``  -- two text boxes that intersect (overprinted step labels, a title over tick labels), or
  a legend's frame over a text outside it (a legend hiding an axis label);
* ``no label`` -- an axis that draws tick labels but has no label;
* ``no unit``  -- an axis label without a unit in parentheses (dimensionless quantities -- a
  multiplier ρ, a ratio t / T -- are named in :data:`DIMENSIONLESS`).

:func:`capture` collects the figures that library code saves (``Figure.savefig`` is wrapped), so that a
test calls the real plotting function and audits what it wrote.
"""
from __future__ import annotations

import contextlib
import re
from types import SimpleNamespace
from typing import Iterator

import matplotlib

matplotlib.use("Agg")
import matplotlib.text  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

#: Axis labels that need no unit (dimensionless): multipliers, ratios.
DIMENSIONLESS = re.compile(r"ρ|rho|t / T|Ω / π")
UNIT = re.compile(r"\([^()]*[A-Za-zΩπ°%][^()]*\)")


def _drawn_texts(fig: Figure) -> list:
    drawn = []
    original = matplotlib.text.Text.draw

    def draw(self, renderer):
        original(self, renderer)
        if self.get_visible() and self.get_text().strip() and getattr(self, "_renderer", None) is not None:
            drawn.append(self)

    matplotlib.text.Text.draw = draw
    try:
        fig.canvas.draw()
    finally:
        matplotlib.text.Text.draw = original
    renderer = fig.canvas.get_renderer()
    out, seen = [], set()
    for t in drawn:
        if id(t) in seen:
            continue
        seen.add(id(t))
        out.append((t, t.get_window_extent(renderer)))
    return out


def audit(fig: Figure, *, min_points: float = 8.0, pad: float = 1.0) -> list[str]:
    """The layout defects of ``fig`` (empty list: none); see the module docstring."""
    texts = _drawn_texts(fig)
    W, H = fig.bbox.width, fig.bbox.height
    defects = []
    for t, bb in texts:
        s = t.get_text().replace("\n", " ")[:60]
        if bb.x0 < -pad or bb.y0 < -pad or bb.x1 > W + pad or bb.y1 > H + pad:
            defects.append(f"outside: {s!r} at ({bb.x0:.0f}, {bb.y0:.0f})-({bb.x1:.0f}, {bb.y1:.0f}) in {W:.0f}x{H:.0f}")
        if t.get_fontsize() < min_points - 1e-9:
            defects.append(f"small: {s!r} at {t.get_fontsize():g} pt")
    for i in range(len(texts)):
        ti, bi = texts[i]
        for j in range(i + 1, len(texts)):
            tj, bj = texts[j]
            w = min(bi.x1, bj.x1) - max(bi.x0, bj.x0)
            h = min(bi.y1, bj.y1) - max(bi.y0, bj.y0)
            if w > pad and h > pad:
                defects.append(f"overlap: {ti.get_text()[:40]!r} and {tj.get_text()[:40]!r} ({w:.0f} x {h:.0f} px)")
    renderer = fig.canvas.get_renderer()
    legends = [lg for lg in list(fig.legends) + [ax.get_legend() for ax in fig.axes] if lg is not None]
    for lg in legends:
        bb = lg.get_window_extent(renderer)
        own = {id(t) for t in lg.get_texts()} | {id(lg.get_title())}
        if bb.x0 < -pad or bb.y0 < -pad or bb.x1 > W + pad or bb.y1 > H + pad:
            defects.append(f"outside: legend ({lg.get_texts()[0].get_text()[:30]!r} ...) at ({bb.x0:.0f}, "
                           f"{bb.y0:.0f})-({bb.x1:.0f}, {bb.y1:.0f}) in {W:.0f}x{H:.0f}")
        for t, tb in texts:
            if id(t) in own:
                continue
            w = min(bb.x1, tb.x1) - max(bb.x0, tb.x0)
            h = min(bb.y1, tb.y1) - max(bb.y0, tb.y0)
            if w > pad and h > pad:
                defects.append(f"overlap: legend ({lg.get_texts()[0].get_text()[:30]!r} ...) over "
                               f"{t.get_text()[:40]!r} ({w:.0f} x {h:.0f} px)")
    drawn = {id(t) for t, _ in texts}
    for i, ax in enumerate(fig.axes):
        if not ax.axison or getattr(ax, "_colorbar", None) is not None or ax.get_label() == "<colorbar>":
            continue
        for name, axis, label in (("x", ax.xaxis, ax.get_xlabel()), ("y", ax.yaxis, ax.get_ylabel())):
            if not any(id(t) in drawn for t in axis.get_ticklabels(which="both")):
                continue  # no tick labels drawn (shared axis, hidden): the neighbour carries the label
            if not label.strip():
                defects.append(f"no label: {name}-axis of axes {i} ({ax.get_title()[:40]!r})")
            elif not (UNIT.search(label) or DIMENSIONLESS.search(label)):
                defects.append(f"no unit: {name}-axis label {label!r} of axes {i}")
    return defects


@contextlib.contextmanager
def capture() -> Iterator[list]:
    """Collect one record per ``Figure.savefig`` inside the block: ``path``, ``defects`` (:func:`audit`) and
    ``texts`` (every drawn text, for checks of what a figure says)."""
    saved: list = []
    original = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        defects = audit(self)
        texts = [t.get_text() for t, _ in _drawn_texts(self)]
        saved.append(SimpleNamespace(path=str(fname), defects=defects, texts=texts))
        return original(self, fname, *args, **kwargs)

    Figure.savefig = savefig
    try:
        yield saved
    finally:
        Figure.savefig = original
