#!/usr/bin/env python3
"""Speed and agreement of the generic model-file path on the built-in single link.

For each Table 3 case (Omega = 2 pi .. 8 pi, Table 3 gains), measured in one
run at the same mesh:

* the generic path (``linearize.analyze("single-link", ...)``): orbit,
  linearisation, Floquet (exponential midpoint, ``--steps``), with CPU and wall
  seconds per stage; the orbit split into its own stages (model build, simulated
  guess, Newton, accurate tangent blocks) and the one-period shooting check in
  Exudyn (the orbit's acceptance check, on by default in ``find_orbit``) reported
  separately, with the collocation residual and the shooting defect reached;
* the hand-derived route (``_link_oracle.link_floquet.exudyn_floquet``, the test suite's oracle) at the
  same samples and steps: its dominant (hub) multiplier is the reference the
  generic one must equal to 1e-6;
* the direct Exudyn monodromy (``direct_monodromy``, 2 n + 1 one-period
  Exudyn runs) as the brute-force baseline (``--direct``, slow).

Target: orbit + linearisation + Floquet <= 2 s per Omega at 8 elements
(``target_2s`` on wall clock; on a loaded machine read the CPU column).

Orbit stage, measured (CPU seconds, min of 2-3 runs in one process, 8 elements, 32
samples, loaded 2-core machine; ``find_orbit(verify=False)`` + ``linearize_orbit`` +
the shooting check on its own):

=========  ==========================  ==========================  ============
Omega      orbit before (its)          orbit after (its)           shooting
=========  ==========================  ==========================  ============
2 pi       0.74 (6)                    0.48 (4)                    0.07
4 pi       0.75 (10)                   0.63 (6)                    0.06
6 pi       4.01 (44, continuation)     0.63 (7)                    0.07
8 pi       4.34 (58, continuation)     0.72 (8)                    0.06
=========  ==========================  ==========================  ============

linearisation 0.02 s CPU throughout; residuals after 2.3e-9, 6.4e-10, 3.1e-10,
1.1e-10 (tolerance 1e-6, unchanged), shooting defects 2e-5 .. 1e-4 (tolerance
1e-2).  "before" is the damped-Newton-only orbit solver, "after" the full-step
Newton with the quasi-static fallback and the compressed reaction stiffness.
Two-link arm (default mesh), same measurement: 1.07 -> 0.67 s at 2 pi,
0.99 -> 1.02 s at 4 pi (no continuation before either).

Floquet stage, measured (this script, 8 elements, 32 samples, Table 3 gains, loaded
2-core machine, ``--no-shooting``): default ``analyze`` (frozen-modal frame, two nested
frames, 128 exponential-midpoint steps Richardson-extrapolated with 64 and 32, a 16-step
solve checking the estimate's premise) against (a) the hand route's linearisation
propagated to convergence (``--converged-steps``, the reference: this column also
holds the two linearisations' disagreement) and (b) the generic linearisation itself
propagated to convergence (the propagator error, which the estimate claims to bound):

=========  ===========  ==================  ==================  ============
Omega      Floquet CPU  vs hand converged   propagator error    estimate
=========  ===========  ==================  ==================  ============
2 pi       0.93 s       8.7e-10             5.9e-13             1.8e-9
4 pi       0.87 s       3.2e-9              3.2e-9              4.6e-8
6 pi       0.82 s       7.9e-8              7.4e-8              1.3e-6
8 pi       0.77 s       3.3e-7              3.3e-7              4.9e-6
=========  ===========  ==================  ==================  ============

Before (512 steps in the model's own coordinates): ~4 s, errors 6.5e-5 (4 pi) ..
5.2e-3 (8 pi), with step-doubling estimates up to 25x too small.  Generic path
(orbit + linearisation + Floquet, no shooting check): 1.69, 1.80, 1.64, 1.55 s CPU
in the same run.  At 2 pi the distance to the hand route (8.7e-10) is the two
linearisations' agreement, not the propagator's error (5.9e-13).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# the hand-derived link is the test suite's independent oracle (tests/_link_oracle)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

TABLE3 = [(2, 37.1617, 29.2410), (4, 28.7617, 11.7501), (6, 22.2666, 6.7208), (8, 23.0147, 6.8628)]


def main(argv=None) -> int:
    from linearize.analysis import analyze
    from _link_oracle.link_floquet import direct_monodromy, exudyn_floquet

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=8)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--steps", type=int, default=None,
                    help="generic path's propagator steps (default: analyze's default, frozen-modal frame)")
    ap.add_argument("--hand-steps", type=int, default=512, help="exponential-midpoint steps of the hand route")
    ap.add_argument("--converged-steps", type=int, default=1024,
                    help="steps of the converged hand-route reference (frozen-modal frame, extrapolated)")
    ap.add_argument("--cases", default="2,4,6,8", help="Omega / pi of the Table 3 cases to run")
    ap.add_argument("--direct", action="store_true", help="also the direct Exudyn monodromy (slow)")
    ap.add_argument("--no-shooting", action="store_true", help="skip the orbit's shooting check in Exudyn")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    wanted = {int(c) for c in args.cases.split(",")}
    rows = []
    for k, kp, kd in TABLE3:
        if k not in wanted:
            continue
        omega = k * math.pi
        tic, ctic = time.perf_counter(), time.process_time()
        steps = {} if args.steps is None else {"n_steps": args.steps}
        res = analyze("single-link", omega, kp=kp, kd=kd, samples=args.samples, **steps,
                      verify_orbit=not args.no_shooting, elements=args.elements)
        orbit_t, orbit_c = res.orbit.timings, res.orbit.cpu_timings
        # orbit + linearisation + Floquet, without the shooting check (measured on its own)
        t_generic = time.perf_counter() - tic - orbit_t.get("shooting", 0.0)
        c_generic = time.process_time() - ctic - orbit_c.get("shooting", 0.0)
        tic = time.perf_counter()
        ref = exudyn_floquet(omega=omega, kp=kp, kd=kd, elements=args.elements, samples=args.samples,
                             n_steps=args.hand_steps, verify_orbit=False)
        t_hand = time.perf_counter() - tic
        row = {
            "omega_over_pi": k, "kp": kp, "kd": kd,
            "generic_dominant": [res.dominant_multiplier.real, res.dominant_multiplier.imag],
            "generic_mode": next((m.mode for mu, m in zip(res.floquet.multipliers, res.modes)
                                  if mu == res.dominant_multiplier), None),
            "hand_dominant": [ref.dominant_multiplier.real, ref.dominant_multiplier.imag],
            "difference": abs(res.dominant_multiplier - ref.dominant_multiplier),
            "generic_error_estimate": res.floquet.error_estimate,
            "hand_error_estimate": ref.floquet.error_estimate,
            "orbit_residual": res.orbit.residual,
            "orbit_tolerance": res.orbit.tolerance,
            "orbit_newton_iterations": res.orbit.iterations,
            "shooting_defect": res.orbit.shooting_residual,
            "seconds_generic": t_generic,
            "cpu_seconds_generic": c_generic,
            "seconds_generic_by_stage": res.timings,
            "cpu_seconds_generic_by_stage": res.cpu_timings,
            "seconds_orbit_by_stage": orbit_t,
            "cpu_seconds_orbit_by_stage": orbit_c,
            "seconds_hand": t_hand,
            "target_2s": t_generic <= 2.0,
        }
        # the hand route's linearisation propagated to convergence: the reference of the 1e-6 target
        import numpy as np

        from stability.modal import modal_floquet

        conv = modal_floquet(ref.linearization, method="magnus2", n_steps=args.converged_steps, accuracy="moduli",
                             extrapolate=True)
        hand_conv = conv.multipliers[np.argmin(np.abs(conv.multipliers - res.dominant_multiplier))]
        # the generic linearisation itself propagated to convergence: what the estimate claims to bound
        same = modal_floquet(res.linearization, method="magnus2", n_steps=args.converged_steps, accuracy="moduli",
                             extrapolate=True)
        same_conv = same.multipliers[np.argmin(np.abs(same.multipliers - res.dominant_multiplier))]
        row.update({
            "floquet_steps": int(res.floquet.n_steps),
            "floquet_cpu_seconds": res.cpu_timings["floquet"],
            "generic_dominant_error_estimate": res.dominant_error_estimate,
            "hand_converged_dominant": [hand_conv.real, hand_conv.imag],
            "hand_converged_error_estimate": conv.error_estimate,
            "error_vs_hand_converged": abs(res.dominant_multiplier - hand_conv) / abs(hand_conv),
            "propagator_error": abs(abs(res.dominant_multiplier) - abs(same_conv)) / abs(same_conv),
            "same_converged_error_estimate": same.error_estimate,
        })
        if args.direct:
            tic = time.perf_counter()
            d = direct_monodromy(ref.orbit, kp=kp, kd=kd)
            row["seconds_direct"] = time.perf_counter() - tic
            row["direct_dominant"] = [d.dominant_multiplier.real, d.dominant_multiplier.imag]
        rows.append(row)
        if not args.json:
            cpu = res.cpu_timings
            print(f"{k}pi: generic {abs(res.dominant_multiplier):.9f} ({row['generic_mode']}), hand "
                  f"{abs(ref.dominant_multiplier):.9f}, |diff| {row['difference']:.1e}; orbit residual "
                  f"{res.orbit.residual:.1e} ({res.orbit.iterations} Newton it.), shooting defect "
                  f"{res.orbit.shooting_residual:.1e}\n"
                  f"    generic CPU {c_generic:.2f} s (wall {t_generic:.2f}): orbit "
                  f"{cpu['orbit'] - orbit_c.get('shooting', 0.0):.2f} "
                  f"[{', '.join(f'{st} {v:.2f}' for st, v in orbit_c.items() if st != 'shooting')}], "
                  f"linearisation {cpu['linearization']:.2f}, Floquet {cpu['floquet']:.2f}, labels {cpu['labels']:.2f}; "
                  f"shooting check {orbit_c.get('shooting', 0.0):.2f} (wall {orbit_t.get('shooting', 0.0):.2f}); "
                  f"hand {t_hand:.2f} s wall"
                  + (f", direct {row['seconds_direct']:.1f} s wall ({abs(d.dominant_multiplier):.6f})"
                     if args.direct else ""),
                  flush=True)
            print(f"    Floquet: {row['floquet_steps']} steps (frozen-modal, extrapolated), CPU "
                  f"{row['floquet_cpu_seconds']:.2f} s; dominant vs hand route converged "
                  f"{row['error_vs_hand_converged']:.1e}, modulus vs the same linearisation converged (propagator "
                  f"error) {row['propagator_error']:.1e} (estimate {row['generic_dominant_error_estimate']:.1e})",
                  flush=True)
    if args.json:
        print(json.dumps({"elements": args.elements, "samples": args.samples, "steps": args.steps, "cases": rows},
                         indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
