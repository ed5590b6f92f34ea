#!/usr/bin/env python3
"""Wall time of the four Table 3 tunings, and Taguchi vs direct optimisers.

Prints, per case (Omega = 2pi..8pi, rho_d = 0.3, 0.3, 0.3, 0.4): Taguchi
time and evaluations, Nelder-Mead and differential-evolution evaluations and
time, all measured in this run.  The four tunings run in parallel, one per
worker process (``--workers``, default 2), the target being < 2 s in
total on 2 cores.  Writes ``taguchi_speed.json`` to ``--out`` (results/).
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import math
import time
from pathlib import Path

CASES = [(2, 0.3), (4, 0.3), (6, 0.3), (8, 0.4)]


def _tune_case(case):
    from mbs_models.reduced import ReducedModel
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    k, rho_d = case
    t0 = time.perf_counter()
    res = taguchi_tune(GainObjective(ReducedModel(omega=k * math.pi)), TuningConfig(target=rho_d))
    return {"case": k, "target": rho_d, "kp": res.kp, "kd": res.kd, "spectral_radius": res.spectral_radius,
            "evaluations": res.evaluations, "converged": res.converged, "time_s": time.perf_counter() - t0}


def _warm(_=None):
    import stability  # noqa: F401  (import cost is not tuning time)
    import taguchi  # noqa: F401
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="skip differential evolution")
    args = ap.parse_args(argv)

    from mbs_models.reduced import ReducedModel
    from taguchi.direct import direct_tune
    from taguchi.tuning import GainObjective, TuningConfig

    # serial timings per case
    _warm()
    serial = [_tune_case(c) for c in CASES]
    # the four tunings in parallel (pool started and warmed before the clock)
    with cf.ProcessPoolExecutor(max_workers=args.workers) as pool:
        list(pool.map(_warm, range(args.workers)))
        t0 = time.perf_counter()
        parallel = list(pool.map(_tune_case, CASES))
        wall_parallel = time.perf_counter() - t0

    direct = []
    for k, rho_d in CASES:
        obj = GainObjective(ReducedModel(omega=k * math.pi))
        cfg = TuningConfig(target=rho_d, max_evaluations=2000)
        row = {"case": k, "nelder-mead": direct_tune(obj, cfg, "nelder-mead").to_dict()}
        if not args.quick:
            row["differential-evolution"] = direct_tune(obj, cfg, "differential-evolution").to_dict()
        direct.append(row)

    print(f"{'Omega':>6} {'rho_d':>6} | {'Taguchi s':>9} {'evals':>6} | {'NM s':>7} {'evals':>6} | {'DE s':>7} {'evals':>6}")
    for s, d in zip(serial, direct):
        nm = d["nelder-mead"]
        de = d.get("differential-evolution")
        de_txt = f"{de['elapsed']:7.3f} {de['evaluations']:6d}" if de else f"{'-':>7} {'-':>6}"
        print(f"{s['case']:>4}pi {s['target']:>6} | {s['time_s']:9.3f} {s['evaluations']:6d} | "
              f"{nm['elapsed']:7.3f} {nm['evaluations']:6d} | {de_txt}")
    total_serial = sum(s["time_s"] for s in serial)
    print(f"\nTaguchi, four Table 3 tunings: {total_serial:.3f} s serial, {wall_parallel:.3f} s wall on "
          f"{args.workers} worker processes (target < 2 s)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "taguchi_speed.json").write_text(json.dumps(
        {"serial": serial, "parallel": parallel, "wall_parallel_s": wall_parallel,
         "total_serial_s": total_serial, "direct": direct}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
