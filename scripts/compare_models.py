#!/usr/bin/env python3
"""Compare the dominant Floquet multipliers of the reduced and the Exudyn models.

Writes ``models.json`` and ``models.md`` to ``results/`` (or ``--out``): for
Omega = 2pi, 4pi, 6pi, 8pi, uncontrolled and with the paper's Table 3 gains,
the reduced model (printed constants), the Exudyn linearisation about the true
periodic orbit and about the undeformed rigid motion, and the direct
monodromy of Exudyn's nonlinear model.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# the hand-derived link is the test suite's independent oracle (tests/_link_oracle)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def main(argv=None) -> int:
    from tqdm import tqdm

    from _link_oracle.model_comparison import comparison_markdown, compare_models

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results", help="output folder (default results/)")
    ap.add_argument("--elements", type=int, default=8, help="ANCF elements (default 8)")
    ap.add_argument("--samples", type=int, default=32, help="orbit/linearisation samples per period")
    ap.add_argument("--no-direct", action="store_true", help="skip the (slow) direct Exudyn monodromy")
    ap.add_argument("--fast", action="store_true", help="2 elements, 16 samples, Omega = 2pi only (tests)")
    args = ap.parse_args(argv)
    kwargs = dict(elements=args.elements, samples=args.samples, direct=not args.no_direct)
    if args.fast:
        kwargs.update(elements=2, samples=16, omegas=(2,))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n_cases = 2 * len(kwargs.get("omegas", (2, 4, 6, 8)))
    with tqdm(total=n_cases, desc="compare models", disable=None) as bar:
        rows = compare_models(progress=lambda s: (bar.set_postfix_str(s), bar.update(0)), **kwargs)
        bar.update(n_cases)
    data = {"elements": kwargs["elements"], "samples": kwargs["samples"], "rows": [r.to_dict() for r in rows]}
    (out / "models.json").write_text(json.dumps(data, indent=2))
    md = comparison_markdown(rows, kwargs["elements"])
    (out / "models.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
