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
import math
from pathlib import Path

import numpy as np

from mbs_models.reduced import ReducedModel
from stability import floquet

#: Table 2 of the paper (p. 489 of the proceedings), moduli as printed.
PRINTED = {
    2: [13.7797, 0.0706, 0.5651, 0.5651],
    4: [3.7506, 0.2628, 0.7517, 0.7517],
    6: [2.4175, 0.4097, 0.8268, 0.8268],
    8: [1.9396, 0.5119, 0.8674, 0.8674],
}


def liouville_error(moduli, trace_integral: float) -> float:
    """Relative error of ``prod |rho_i|`` against ``exp(int tr P)``."""
    return abs(math.expm1(float(np.sum(np.log(moduli))) - trace_integral))


def compute(constants: str = "paper") -> list[dict]:
    rows = []
    for k, printed in PRINTED.items():
        model = ReducedModel(omega=k * math.pi, constants=constants)
        res = floquet(model)
        ours = sorted(res.moduli.tolist(), reverse=True)
        printed_sorted = sorted(printed, reverse=True)
        rows.append(
            {
                "omega": k * math.pi,
                "omega_over_pi": k,
                "printed_moduli": printed,
                "moduli": ours,
                "multipliers": [[float(z.real), float(z.imag)] for z in res.multipliers],
                "exp_trace_integral": math.exp(res.trace_integral),
                "liouville_printed": liouville_error(printed_sorted, res.trace_integral),
                "liouville_ours": liouville_error(ours, res.trace_integral),
                "error_estimate": res.error_estimate,
                "n_steps": res.n_steps,
                "method": res.method,
                "relative_difference_dominant": ours[0] / printed_sorted[0] - 1,
                "relative_difference_pair": ours[1] / printed[2] - 1,
                "relative_difference_smallest": ours[-1] / printed_sorted[-1] - 1,
            }
        )
    return rows


def to_markdown(rows: list[dict]) -> str:
    out = [
        "# Table 2 reproduced: Floquet multipliers of the uncontrolled manipulator",
        "",
        "Reduced one-mode model (paper Eqs. 20-25, mode constants as printed), default Floquet method",
        "(6th-order Magnus, step doubling). *Printed* = Table 2 of the paper. Liouville: relative error of",
        "prod |rho_i| against exp(int_0^T tr P dt) (= det Phi(T)).",
        "",
        "| Omega | printed rho1, rho2, rho3=rho4 | ours rho1, rho4 (smallest), rho2=rho3 | exp(int tr P) | Liouville printed | Liouville ours |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        p, m = r["printed_moduli"], r["moduli"]
        out.append(
            f"| {r['omega_over_pi']}pi | {p[0]}, {p[1]}, {p[2]} | {m[0]:.6f}, {m[3]:.6f}, {m[1]:.6f} | "
            f"{r['exp_trace_integral']:.6f} | {r['liouville_printed']:.2%} | {r['liouville_ours']:.1e} |"
        )
    out += [
        "",
        "The dominant and smallest moduli agree with the printed ones to the printed digits. The printed",
        "complex pair does not: its product with the real multipliers misses det Phi(T) = exp(int tr P dt)",
        "by the percentage in the 'Liouville printed' column, i.e. the printed pair carries a ~2 % error;",
        "ours satisfies Liouville's formula to rounding.",
    ]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results", help="output folder (default results/)")
    ap.add_argument("--constants", choices=["paper", "derived"], default="paper")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = compute(args.constants)
    (out / "table2.json").write_text(json.dumps({"constants": args.constants, "rows": rows}, indent=2))
    (out / "table2.md").write_text(to_markdown(rows))
    print(to_markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
