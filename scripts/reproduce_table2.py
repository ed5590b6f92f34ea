#!/usr/bin/env python3
"""Reproduce Table 2 of the paper: Floquet multipliers of the uncontrolled manipulator.

Writes ``table2.json`` and ``table2.md`` to ``results/`` (or ``--out``): for
Omega = 2pi, 4pi, 6pi, 8pi our four moduli beside the printed ones, and a
Liouville column: ``prod |rho_i|`` against ``exp(int_0^T tr P dt)``.  The
printed complex pair violates Liouville's formula by 2-4 %; ours satisfy it.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from flexstab.paper_tables import table2_markdown, table2_rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results", help="output folder (default results/)")
    ap.add_argument("--constants", choices=["paper", "derived"], default="paper")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = table2_rows(args.constants)
    (out / "table2.json").write_text(json.dumps({"constants": args.constants, "rows": rows}, indent=2))
    (out / "table2.md").write_text(table2_markdown(rows))
    print(table2_markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
