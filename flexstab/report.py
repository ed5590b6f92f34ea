"""The study report as data: paragraphs, tables and figures, rendered to Markdown and HTML.

A stage of :mod:`flexstab.study` returns a list of *blocks* (plain JSON-ready
dicts, so that a finished stage can be stored and its section re-rendered
when the study is resumed):

* ``{"kind": "text", "text": str}`` -- a paragraph;
* ``{"kind": "table", "header": [str, ...], "rows": [[str, ...], ...]}``;
* ``{"kind": "figure", "file": str, "caption": str}``.

:func:`to_markdown` escapes ``|`` inside table cells (``\\|``), so that a
heading such as ``max|rho|`` stays one cell; :func:`to_html` builds the HTML
tables from the blocks themselves, not by re-parsing the Markdown.
:func:`markdown_table_cells` splits a Markdown table row the way a
GitHub-flavoured renderer does (escaped pipes stay in the cell); the tests
use it to check that every row has as many cells as the header.
"""
from __future__ import annotations

import html
import math
import re
from typing import Iterable, Sequence

__all__ = [
    "text",
    "table",
    "figure",
    "check_table",
    "to_markdown",
    "to_html",
    "markdown_table",
    "markdown_table_cells",
    "percent",
    "relative",
    "fixed",
    "pi_multiple",
    "omega_text",
]


def text(body: str) -> dict:
    """A paragraph block (line breaks inside ``body`` are joined by the renderers)."""
    return {"kind": "text", "text": str(body)}


def check_table(header: Sequence[str], rows: Iterable[Sequence[object]]) -> list[list[str]]:
    """Rows as lists of strings; raise ``ValueError`` if a row's length differs from the header's."""
    out = []
    for i, row in enumerate(rows):
        cells = [str(c) for c in row]
        if len(cells) != len(header):
            raise ValueError(f"table row {i} has {len(cells)} cells, the header {len(header)}: {cells!r}")
        out.append(cells)
    return out


def table(header: Sequence[str], rows: Iterable[Sequence[object]]) -> dict:
    """A table block; every row must have as many cells as ``header``."""
    header = [str(h) for h in header]
    return {"kind": "table", "header": header, "rows": check_table(header, rows)}


def figure(file: str, caption: str = "") -> dict:
    """A figure block (``file`` relative to the report's folder)."""
    return {"kind": "figure", "file": str(file), "caption": str(caption)}


def percent(x: float, digits: int = 2, sign: bool = False) -> str:
    """``x`` as a percentage, without a negative zero (``-0.00 %`` reads as a result; it is rounding)."""
    if x is None or not math.isfinite(x):
        return "n/a"
    value = 100.0 * x
    if round(value, digits) == 0:
        value = 0.0
    return f"{value:{'+' if sign and value != 0 else ''}.{digits}f} %"


def relative(x: float, sign: bool = True) -> str:
    """A relative difference: a percentage from 0.01 % up, else in scientific notation (never ``0.00 %``)."""
    if x is None or not math.isfinite(x):
        return "n/a"
    if x == 0:
        return "0"
    if abs(x) >= 1e-4:
        return percent(x, 2, sign)
    return f"{x:{'+' if sign else ''}.1e}"


def fixed(x: float, digits: int) -> str:
    """``x`` with ``digits`` decimals, without a negative zero."""
    if x is None or not math.isfinite(x):
        return "n/a"
    if round(x, digits) == 0:
        x = 0.0
    return f"{x:.{digits}f}"


def pi_multiple(omega: float) -> str:
    """``omega`` as a multiple of pi: ``π``, ``2π``, ``0.5π``."""
    k = f"{omega / math.pi:.4g}"
    return "π" if k == "1" else f"{k}π"


def omega_text(omega: float) -> str:
    """``omega`` in units of pi rad/s, e.g. ``2π rad/s``."""
    return f"{omega / math.pi:.4g}π rad/s"


# ----------------------------------------------------------------------------- Markdown
def _md_cell(cell: str) -> str:
    return str(cell).replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> list[str]:
    """Lines of a GitHub-flavoured Markdown table, ``|`` in cells escaped."""
    rows = check_table(header, rows)
    lines = ["| " + " | ".join(_md_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md_cell(c) for c in r) + " |" for r in rows]
    return lines


_SPLIT = re.compile(r"(?<!\\)\|")


def markdown_table_cells(line: str) -> list[str]:
    """Cells of one Markdown table row: split at unescaped ``|``, escapes removed."""
    s = line.strip()
    if s.startswith("|"):
        s = s[1:]
    if s.endswith("|") and not s.endswith("\\|"):
        s = s[:-1]
    return [c.strip().replace("\\|", "|").replace("\\\\", "\\") for c in _SPLIT.split(s)]


def to_markdown(title: str, preamble: Sequence[dict], sections: Sequence[tuple[str, Sequence[dict]]]) -> str:
    """Render ``# title``, the preamble blocks and one ``## heading`` per section."""
    out = [f"# {title}", ""]
    for heading, blocks in [(None, preamble)] + list(sections):
        if heading is not None:
            out += [f"## {heading}", ""]
        for b in blocks:
            if b["kind"] == "text":
                out += [b["text"].strip(), ""]
            elif b["kind"] == "table":
                out += markdown_table(b["header"], b["rows"]) + [""]
            elif b["kind"] == "figure":
                out += [f"![{b['file']}]({b['file']})", ""]
                if b["caption"]:
                    out += [f"*{b['caption']}*", ""]
            else:  # pragma: no cover - programming error
                raise ValueError(f"unknown block kind {b['kind']!r}")
    return "\n".join(out).rstrip() + "\n"


# ----------------------------------------------------------------------------- HTML
_CSS = (
    "body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 1em;line-height:1.4}"
    "table{border-collapse:collapse;margin:0.5em 0}"
    "td,th{border:1px solid #999;padding:2px 6px;font-size:90%;text-align:right}"
    "th{background:#eee}td:first-child,th:first-child{text-align:left}"
    "img{max-width:100%}figure{margin:1em 0}figcaption{font-size:90%;color:#333}"
    "code{background:#f4f4f4}"
)


def _inline(s: str) -> str:
    """HTML-escape, then render Markdown's ``code`` and **bold** spans."""
    s = html.escape(s)
    s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
    s = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", s)
    return re.sub(r"(?<![\w*])\*([^*\s][^*]*)\*(?![\w*])", r"<em>\1</em>", s)


def to_html(title: str, preamble: Sequence[dict], sections: Sequence[tuple[str, Sequence[dict]]]) -> str:
    """Render the same document as :func:`to_markdown`, as a standalone HTML page."""
    out = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           f"<style>{_CSS}</style></head><body>", f"<h1>{html.escape(title)}</h1>"]
    for heading, blocks in [(None, preamble)] + list(sections):
        if heading is not None:
            out.append(f"<h2>{html.escape(heading)}</h2>")
        for b in blocks:
            if b["kind"] == "text":
                out.append("<p>" + _inline(" ".join(b["text"].split())) + "</p>")
            elif b["kind"] == "table":
                out.append("<table>")
                out.append("<tr>" + "".join(f"<th>{_inline(h)}</th>" for h in b["header"]) + "</tr>")
                for r in b["rows"]:
                    out.append("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>")
                out.append("</table>")
            elif b["kind"] == "figure":
                src = html.escape(b["file"], quote=True)
                out.append(f"<figure><img src=\"{src}\" alt=\"{html.escape(b['file'], quote=True)}\">"
                           + (f"<figcaption>{_inline(b['caption'])}</figcaption>" if b["caption"] else "")
                           + "</figure>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"
