#!/usr/bin/env python3
"""Speed and agreement of the generic model-file path on the built-in single link.

For each Table 3 case (Omega = 2 pi .. 8 pi, Table 3 gains), measured in one
run at the same mesh:

* the generic path (``linearize.analyze("single-link", ...)``): orbit,
  linearisation, Floquet (exponential midpoint, ``--steps``), with timings per stage;
* the hand-derived route (``linearize.link_floquet.exudyn_floquet``) at the
  same samples and steps: its dominant (hub) multiplier is the reference the
  generic one must equal to 1e-6 (issue 9);
* the direct Exudyn monodromy (``direct_monodromy``, 2 n + 1 one-period
  Exudyn runs) as the brute-force baseline (``--direct``, slow).

Target (issue 9): orbit + linearisation + Floquet <= 2 s per Omega at 8 elements.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

TABLE3 = [(2, 37.1617, 29.2410), (4, 28.7617, 11.7501), (6, 22.2666, 6.7208), (8, 23.0147, 6.8628)]


def main(argv=None) -> int:
    from linearize.analysis import analyze
    from linearize.link_floquet import direct_monodromy, exudyn_floquet

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=8)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--steps", type=int, default=512, help="exponential-midpoint steps (both routes)")
    ap.add_argument("--cases", default="2,4,6,8", help="Omega / pi of the Table 3 cases to run")
    ap.add_argument("--direct", action="store_true", help="also the direct Exudyn monodromy (slow)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    wanted = {int(c) for c in args.cases.split(",")}
    rows = []
    for k, kp, kd in TABLE3:
        if k not in wanted:
            continue
        omega = k * math.pi
        tic = time.perf_counter()
        res = analyze("single-link", omega, kp=kp, kd=kd, samples=args.samples, n_steps=args.steps,
                      verify_orbit=False, elements=args.elements)
        t_generic = time.perf_counter() - tic
        tic = time.perf_counter()
        ref = exudyn_floquet(omega=omega, kp=kp, kd=kd, elements=args.elements, samples=args.samples,
                             n_steps=args.steps, verify_orbit=False)
        t_hand = time.perf_counter() - tic
        row = {
            "omega_over_pi": k, "kp": kp, "kd": kd,
            "generic_dominant": [res.dominant_multiplier.real, res.dominant_multiplier.imag],
            "generic_mode": next((m["mode"] for mu, m in zip(res.floquet.multipliers, res.modes)
                                  if mu == res.dominant_multiplier), None),
            "hand_dominant": [ref.dominant_multiplier.real, ref.dominant_multiplier.imag],
            "difference": abs(res.dominant_multiplier - ref.dominant_multiplier),
            "generic_error_estimate": res.floquet.error_estimate,
            "hand_error_estimate": ref.floquet.error_estimate,
            "orbit_residual": res.orbit.residual,
            "seconds_generic": t_generic,
            "seconds_generic_by_stage": res.timings,
            "seconds_hand": t_hand,
            "target_2s": t_generic <= 2.0,
        }
        if args.direct:
            tic = time.perf_counter()
            d = direct_monodromy(ref.orbit, kp=kp, kd=kd)
            row["seconds_direct"] = time.perf_counter() - tic
            row["direct_dominant"] = [d.dominant_multiplier.real, d.dominant_multiplier.imag]
        rows.append(row)
        if not args.json:
            print(f"{k}pi: generic {abs(res.dominant_multiplier):.9f} ({row['generic_mode']}), hand "
                  f"{abs(ref.dominant_multiplier):.9f}, |diff| {row['difference']:.1e}; generic {t_generic:.2f} s "
                  f"{ {s: round(v, 2) for s, v in res.timings.items()} }, hand {t_hand:.2f} s"
                  + (f", direct {row['seconds_direct']:.1f} s ({abs(d.dominant_multiplier):.6f})" if args.direct else ""),
                  flush=True)
    if args.json:
        print(json.dumps({"elements": args.elements, "samples": args.samples, "steps": args.steps, "cases": rows},
                         indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
