#!/usr/bin/env python3
"""Speed of the Exudyn Floquet route against the direct Exudyn monodromy.

One case (default Omega = 2 pi, Table 3 gains, 8 elements), measured in one
run: periodic orbit + finite-difference linearisation + Floquet multipliers,
against the direct monodromy from 2n + 1 one-period Exudyn simulations, and
the agreement of their dominant multipliers.  Targets: the
linearisation route < 10 s and >= 5x faster than the direct monodromy at
equal accuracy on the dominant multiplier.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main(argv=None) -> int:
    from _link_oracle.link_floquet import direct_monodromy, exudyn_floquet

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=8)
    ap.add_argument("--omega-pi", type=float, default=2.0, help="Omega / pi (default 2)")
    ap.add_argument("--kp", type=float, default=37.1617)
    ap.add_argument("--kd", type=float, default=29.2410)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--steps", type=int, default=128, help="exponential-midpoint steps (the error estimate compares with half as many)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    omega = args.omega_pi * math.pi

    tic = time.perf_counter()
    ex = exudyn_floquet(omega=omega, kp=args.kp, kd=args.kd, elements=args.elements,
                        samples=args.samples, n_steps=args.steps, verify_orbit=False)
    t_route = time.perf_counter() - tic
    tic = time.perf_counter()
    d = direct_monodromy(ex.orbit, kp=args.kp, kd=args.kd)
    t_direct = time.perf_counter() - tic
    a, b = abs(ex.dominant_multiplier), abs(d.dominant_multiplier)
    out = {
        "elements": args.elements,
        "omega": omega,
        "kp": args.kp,
        "kd": args.kd,
        "dominant_linearisation": a,
        "dominant_direct": b,
        "relative_difference": abs(a - b) / b,
        "floquet_error_estimate": ex.floquet.error_estimate,
        "seconds_linearisation_route": t_route,
        "seconds_by_stage": ex.timings,
        "seconds_direct": t_direct,
        "direct_simulations": d.simulations,
        "speedup": t_direct / t_route,
        "target_route_under_10s": t_route < 10.0,
        "target_speedup_5x": t_direct / t_route >= 5.0,
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"linearisation route: {t_route:6.2f} s  (orbit {ex.timings['orbit']:.2f}, "
              f"linearisation {ex.timings['linearization']:.2f}, Floquet {ex.timings['floquet']:.2f})")
        print(f"direct monodromy   : {t_direct:6.2f} s  ({d.simulations} Exudyn runs)")
        print(f"speed-up           : {t_direct / t_route:6.1f} x")
        print(f"dominant |rho|     : {a:.7f} (linearisation, {ex.dominant_mode}) vs {b:.7f} (direct), "
              f"relative difference {abs(a - b) / b:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
