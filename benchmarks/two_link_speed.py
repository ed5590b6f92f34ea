#!/usr/bin/env python3
"""Speed of the two-link arm: orbit + linearisation + Floquet per Omega, and one four-gain tuning (CPU seconds).

Targets: orbit + linearisation + Floquet <= 5 s per Omega at the default mesh; one
four-gain Taguchi tuning <= 60 s on 2 cores.  "Floquet" is the labelling pass (magnus2, 512 steps,
prepared workspace) plus Hill's method for the dominant drive-mode multiplier (16 harmonics).
Baseline measured in the same run: the time-stepping product that reaches the same accuracy
(streamed magnus2 at 32768 steps, ~1e-6 from Hill; ``--baseline``), and Nelder-Mead / differential
evolution on the same Hill objective (``--compare``, serial).  CPU = process + reaped children
(``resource.getrusage``).  Writes ``two_link_speed.json`` to ``--out``.
"""
from __future__ import annotations

import argparse
import json
import math
import resource
import time
from pathlib import Path


def cpu() -> float:
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results")
    ap.add_argument("--elements", type=int, default=None, help="elements per link (default: the model's)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--target", type=float, default=0.3)
    ap.add_argument("--compare", action="store_true", help="also Nelder-Mead and differential evolution")
    ap.add_argument("--baseline", action="store_true", help="also the streamed magnus2 product at 32768 steps")
    args = ap.parse_args(argv)

    from flexstab.executor import make_executor
    from flexstab.two_link import check_multiplier, compare_direct_methods, tune_four_gains, two_link_floquet

    rows = []
    for k in (2, 4):
        omega = k * math.pi
        fl = two_link_floquet(omega, args.elements)
        analysis_cpu = sum(fl.cpu_seconds.values())
        row = {"omega": omega, "elements": fl.elements, "analysis_cpu_s": analysis_cpu, "cpu_seconds": fl.cpu_seconds,
               "dominant_uncontrolled": abs(fl.measure.dominant), "mode": fl.measure.mode}
        with make_executor("process", max_workers=args.workers) as ex:
            list(ex.map(abs, range(args.workers)))  # start the workers before the clock
            c0, t0 = cpu(), time.perf_counter()
            tuned = tune_four_gains(fl.linearization, args.target, orbit=fl.orbit, executor=ex)
            t_wall = time.perf_counter() - t0
        t_cpu = cpu() - c0  # children reaped at the pool's shutdown
        row.update({"tuning_cpu_s": t_cpu, "tuning_wall_s": t_wall, "tuning_evaluations": tuned.evaluations,
                    "tuned_gains": list(tuned.gains), "tuned_rho": tuned.spectral_radius, "converged": tuned.converged})
        if args.baseline:
            c0 = cpu()
            chk = check_multiplier(fl.linearization, fl.orbit, tuned.gains)
            row["check"] = chk.to_dict()
            row["check_cpu_s"] = cpu() - c0
        if args.compare:
            row["direct"] = compare_direct_methods(fl.linearization, fl.orbit, args.target)
        rows.append(row)
        print(f"Omega = {k}pi: orbit+lin+Floquet {analysis_cpu:.2f} s CPU "
              f"({', '.join(f'{a} {b:.2f}' for a, b in fl.cpu_seconds.items())}); uncontrolled {abs(fl.measure.dominant):.6f} "
              f"({fl.measure.mode}); tuning {t_cpu:.1f} s CPU / {t_wall:.1f} s wall on {args.workers} workers, "
              f"{tuned.evaluations} evaluations, {tuned.status}, gains {[round(g, 4) for g in tuned.gains]} -> "
              f"{tuned.spectral_radius:.6f}", flush=True)
        if "check" in row:
            c = row["check"]
            print(f"   streamed magnus2: {c['streamed_moduli']} (error estimate {c['magnus_error_estimate']:.2e}), "
                  f"|Hill - magnus2| {c['difference']:.2e}, {row['check_cpu_s']:.1f} s CPU")
        for d in row.get("direct", []):
            print(f"   {d['method']}: {d['evaluations']} evaluations, {d['cpu_s']:.1f} s CPU (serial), {d['status']}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "two_link_speed.json").write_text(json.dumps(rows, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
