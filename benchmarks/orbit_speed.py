#!/usr/bin/env python3
"""CPU seconds per stage of the generic periodic orbit (``linearize.find_orbit``).

For the built-in single link (Table 3 Omegas, ``--elements``) and the two-link
arm (2 pi, 4 pi, default mesh): the orbit's stages (model build, simulated guess,
Newton, accurate tangent blocks), the linearisation (``linearize_orbit``) and the
one-period shooting check in Exudyn on its own, each the minimum over
``--repeat`` runs in one process (CPU time: the machine is shared), with the
collocation residual (tolerance unchanged), the Newton iterations and the
shooting defect.  ``model_file_speed.py`` has the full pipeline beside the hand
route and the direct Exudyn monodromy; its docstring has the before/after table.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _measure(model: str, k: float, repeat: int, **options) -> dict:
    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import _shooting_defect, find_orbit

    best: dict = {}
    for _ in range(repeat):
        c0 = time.process_time()
        orbit = find_orbit(model, k * math.pi, verify=False, **options)
        c1 = time.process_time()
        linearize_orbit(orbit)
        c2 = time.process_time()
        defect = _shooting_defect(orbit.model, orbit.omega, orbit.q, orbit.q_t, orbit.samples)
        c3 = time.process_time()
        stages = {"orbit": c1 - c0, "linearization": c2 - c1, "shooting": c3 - c2}
        stages.update({f"orbit.{s}": v for s, v in orbit.cpu_timings.items() if s != "shooting"})
        for s, v in stages.items():
            best[s] = min(best.get(s, math.inf), v)
    return {"model": model, "omega_over_pi": k, "cpu_seconds": best, "residual": orbit.residual,
            "tolerance": orbit.tolerance, "iterations": orbit.iterations, "shooting_defect": defect}


def main(argv=None) -> int:
    from linearize.periodic_orbit import find_orbit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=8, help="single-link ANCF elements")
    ap.add_argument("--cases", default="2,4,6,8", help="single-link Omega / pi")
    ap.add_argument("--two-link-cases", default="2,4", help="two-link Omega / pi ('' to skip)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    find_orbit("single-link", 2 * math.pi, samples=8, verify=False, elements=1)  # imports, first-call costs
    rows = [_measure("single-link", float(k), args.repeat, elements=args.elements)
            for k in args.cases.split(",") if k]
    rows += [_measure("two-link", float(k), args.repeat) for k in args.two_link_cases.split(",") if k]
    if args.json:
        print(json.dumps({"elements": args.elements, "repeat": args.repeat, "rows": rows}, indent=2))
        return 0
    for r in rows:
        c = r["cpu_seconds"]
        print(f"{r['model']} {r['omega_over_pi']:g} pi: orbit {c['orbit']:.2f} s CPU "
              f"[{', '.join(f'{s[6:]} {v:.2f}' for s, v in c.items() if s.startswith('orbit.'))}], "
              f"linearisation {c['linearization']:.2f}, shooting check {c['shooting']:.2f}; residual "
              f"{r['residual']:.1e} (tol {r['tolerance']:.0e}), {r['iterations']} Newton it., shooting defect "
              f"{r['shooting_defect']:.1e}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
