#!/usr/bin/env python3
"""Reproduce Table 3 of the paper: PD gains tuned by the Taguchi method.

For Omega = 2pi, 4pi, 6pi, 8pi with rho_d = 0.3, 0.3, 0.3, 0.4 this runs
our iterative Taguchi tuning (:func:`taguchi.taguchi_tune`) on the reduced
model, re-checks the tuned gains with the independent ``"paper"`` Floquet
method, re-evaluates the paper's printed gains, and compares with a direct
Nelder-Mead search.  Writes ``table3.json`` and ``table3.md`` to
``results/`` (or ``--out``).

The gains need not equal the printed ones: the set of (kp, kd) with
max|rho| = rho_d is a curve in the gain plane, and any point on it solves
the paper's problem (Eq. 34).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from flexstab.paper_tables import TABLE3_PRINTED, table3_markdown, table3_rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results")
    ap.add_argument("--constants", choices=["paper", "derived"], default="paper")
    ap.add_argument("--array", default=None)
    ap.add_argument("--quick", action="store_true", help="only the first case")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = table3_rows(TABLE3_PRINTED[:1] if args.quick else TABLE3_PRINTED, args.constants, args.array)
    (out / "table3.json").write_text(json.dumps({"constants": args.constants, "rows": rows}, indent=2))
    (out / "table3.md").write_text(table3_markdown(rows))
    print(table3_markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
