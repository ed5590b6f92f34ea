#!/usr/bin/env python3
"""Speed of the two-link arm: orbit + linearisation + Floquet per Omega, and one four-gain tuning.

Targets (issue 11): orbit + linearisation + Floquet <= 5 s per Omega at the
default mesh; one four-gain Taguchi tuning <= 60 s on 2 cores.  Baselines
measured in the same run: the direct Exudyn monodromy (``--direct``, coarse
mesh; 2 r + 1 one-period runs) for the Floquet analysis, and Nelder-Mead /
differential evolution on the same tuning objective (``--compare``).
Writes ``two_link_speed.json`` to ``--out``.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results")
    ap.add_argument("--elements", type=int, default=None, help="elements per link (default: the model's)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--target", type=float, default=0.3)
    ap.add_argument("--steps", type=int, default=2048, help="magnus2 sub-intervals (analysis and tuning loop)")
    ap.add_argument("--compare", action="store_true", help="also Nelder-Mead and differential evolution")
    ap.add_argument("--direct", action="store_true", help="also the direct Exudyn monodromy (2 elements)")
    args = ap.parse_args(argv)

    from flexstab.executor import make_executor
    from flexstab.two_link import MODEL, TUNING_RANGES, LabelledGainObjective, dominant_damped, tune_four_gains
    from linearize.analysis import analyze
    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from mbs_models.model_file import builtin_model
    from taguchi.direct import direct_tune
    from taguchi.tuning import TuningConfig

    opts = {} if args.elements is None else {"elements": args.elements}
    fopts = {"method": "magnus2", "n_steps": args.steps, "error_estimate": False}
    model = builtin_model(MODEL, **opts)
    rows = []
    for k in (2, 4):
        omega = k * math.pi
        t0 = time.perf_counter()
        res = analyze(model, omega, n_steps=args.steps)
        t_analyze = time.perf_counter() - t0
        lin0 = linearize_orbit(res.orbit, 0.0, 0.0)
        with make_executor("process", max_workers=args.workers) as ex:
            list(ex.map(abs, range(args.workers)))  # start the workers before the clock
            t0 = time.perf_counter()
            tuned = tune_four_gains(lin0, args.target, orbit=res.orbit, executor=ex, floquet_options=fopts)
            t_tune = time.perf_counter() - t0
        row = {"omega": omega, "analyze_s": t_analyze, "timings": res.timings,
               "dominant_uncontrolled": abs(res.dominant_multiplier),
               "tuning_s": t_tune, "tuning_evaluations": tuned.evaluations, "tuned_gains": list(tuned.gains),
               "tuned_rho": tuned.spectral_radius, "converged": tuned.converged}
        if args.compare:
            obj = LabelledGainObjective(lin0, res.orbit, fopts)
            cfg = TuningConfig(target=args.target, ranges=TUNING_RANGES, max_evaluations=3000)
            row["direct"] = [direct_tune(obj, cfg, m).to_dict() for m in ("nelder-mead", "differential-evolution")]
        if args.direct:
            from validation.direct_monodromy import direct_monodromy
            from mbs_models.builtin.two_link import build

            o2 = find_orbit(builtin_model(MODEL, elements=2), omega)
            dm = direct_monodromy(build, omega, o2.q[0], o2.q_t[0], o2.torque, elements=2)
            row["direct_monodromy_s"] = dm.wall_time
            row["direct_dominant"] = abs(dominant_damped(dm.multipliers))
        rows.append(row)
        print(f"Omega = {k}pi: orbit+lin+Floquet {t_analyze:.2f} s ({', '.join(f'{a} {b:.2f}' for a, b in res.timings.items())}); "
              f"four-gain tuning {t_tune:.1f} s, {tuned.evaluations} evaluations, {tuned.status}, "
              f"gains {[round(g, 4) for g in tuned.gains]} -> {tuned.spectral_radius:.6f}")
        for d in row.get("direct", []):
            print(f"   {d['method']}: {d['evaluations']} evaluations, {d['elapsed']:.1f} s (serial), {d['status']}")
        if args.direct:
            print(f"   direct Exudyn monodromy (2 elements): {row['direct_monodromy_s']:.1f} s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "two_link_speed.json").write_text(json.dumps(rows, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
