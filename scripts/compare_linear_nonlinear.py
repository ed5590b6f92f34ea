#!/usr/bin/env python3
"""Nonlinear Exudyn closed loop against the linear prediction, four Omega cases.

Writes ``linear_vs_nonlinear.json``, ``linear_vs_nonlinear.md`` and one PNG
per Omega (``linear_vs_nonlinear_omega{2,4,6,8}pi.png``) to ``results/``
(or ``--out``): uncontrolled (paper perturbation and a small one), the
paper's Table 3 gains and our Taguchi gains; hub-angle error and tip
deflection of the nonlinear run with the linearised-Exudyn response and the
``C |rho|^(t/T)`` envelope overlaid.  ``--quick``: 2 elements, 3 periods,
Omega = 2pi only (tests).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main(argv=None) -> int:
    from tqdm import tqdm

    from validation.plots import plot_validation_figure
    from validation.study import CASES, compare_linear_nonlinear, comparison_markdown

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results", help="output folder (default results/)")
    ap.add_argument("--elements", type=int, default=8, help="ANCF elements (default 8)")
    ap.add_argument("--periods", type=int, default=5, help="periods per run (default 5)")
    ap.add_argument("--quick", action="store_true", help="2 elements, 3 periods, Omega = 2pi only")
    args = ap.parse_args(argv)
    kwargs = dict(elements=args.elements, periods=args.periods, omegas=(2, 4, 6, 8))
    if args.quick:
        kwargs.update(elements=2, periods=3, omegas=(2,), samples=16)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tic = time.perf_counter()
    n = len(kwargs["omegas"]) * len(CASES)
    with tqdm(total=n, desc="linear vs nonlinear", disable=None) as bar:
        def step(label: str) -> None:
            bar.set_postfix_str(label)
            bar.update(1)

        rows = compare_linear_nonlinear(progress=step, **kwargs)
    figures = []
    for k in kwargs["omegas"]:
        sel = [r for r in rows if r.omega_over_pi == k]
        path = out / f"linear_vs_nonlinear_omega{k}pi.png"
        plot_validation_figure(
            [r.result for r in sel], path,
            titles=[f"{r.case}: kp = {r.result.kp:.4g}, kd = {r.result.kd:.4g}, δ = {r.result.perturbation:.3g} rad/s"
                    for r in sel],
            suptitle=f"Ω = {k}π: nonlinear Exudyn ({kwargs['elements']} elements) vs linearised Exudyn",
        )
        figures.append(str(path))
    data = {
        "elements": kwargs["elements"],
        "periods": kwargs["periods"],
        "wall_time": time.perf_counter() - tic,
        "figures": [Path(f).name for f in figures],
        "rows": [r.to_dict() for r in rows],
    }
    (out / "linear_vs_nonlinear.json").write_text(json.dumps(data, indent=2))
    md = comparison_markdown(rows, elements=kwargs["elements"], periods=kwargs["periods"], figures=figures)
    (out / "linear_vs_nonlinear.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
