"""Benchmark: one Floquet evaluation inside a tuning loop on the Exudyn plant.

The 8-element Exudyn link at Omega = 2pi, linearised once along its periodic
orbit (68 states).  Compared, in one run, in CPU seconds of this process
(``time.process_time``; run with ``OPENBLAS_NUM_THREADS=1``):

* ``ExudynPlant.spectral_measure(kp, kd)`` -- today's evaluation: the gains
  are written into the sampled ``K, C``, the linearisation is interpolated and
  its mass matrices solved at every Gauss point, balanced, then the magnus2
  product and the mode classification;
* ``PreparedExudynPlant.spectral_measure(kp, kd)`` -- the same scheme at the
  same nodes on a :class:`stability.gains.FloquetWorkspace`: ``P_0`` and the
  two rank-one gain directions sampled and balanced once, so an evaluation is
  the rank-one update, the exponentials, the product, the eigenvalues and the
  classification;

at a handful of gain pairs (median time, largest difference of the measure),
then the whole Taguchi tuning (target 0.3, paper Table 3 rule) with each plant:
the tuned gains and the tuned multiplier must agree to 1e-6.

Usage::

    python benchmarks/tuning_speed.py            # ~3-5 min (plant, evaluations, two tunings)
    python benchmarks/tuning_speed.py --no-tune  # evaluations only
    python benchmarks/tuning_speed.py --out results

Writes ``<out>/tuning_speed.json``.
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from _link_oracle.link_floquet import PreparedExudynPlant, exudyn_plant
from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

CLOCK = time.process_time
#: Gain pairs of the per-evaluation comparison (paper Table 3's 2pi gains among them).
GAINS = [(0.0, 0.0), (10.0, 5.0), (37.1617, 29.2410), (60.0, 40.0), (25.0, 12.0)]
#: Required agreement of the measure and of the tuned multiplier.
AGREEMENT = 1e-6


def _timed(f, repeats: int):
    times, value = [], None
    for _ in range(repeats):
        t0 = CLOCK()
        value = f()
        times.append(CLOCK() - t0)
    return statistics.median(times), value


def run(out: Path, tune: bool = True, repeats: int = 3, verbose: bool = True) -> dict:
    log = (lambda s: print(s, flush=True)) if verbose else (lambda s: None)
    t0 = CLOCK()
    plant = exudyn_plant(omega=2 * math.pi, elements=8)
    plant_s = CLOCK() - t0
    n = 2 * plant.linearization.size
    log(f"plant: {plant.linearization.elements} elements, {n} states, {plant.n_steps} steps "
        f"({plant_s:.1f} s CPU for orbit + linearisation)")
    t0 = CLOCK()
    fast = PreparedExudynPlant(plant)
    _ = fast.workspace
    prepare_s = CLOCK() - t0
    log(f"workspace: {prepare_s:.3f} s CPU (once)")
    rows = []
    for kp, kd in GAINS:
        old_s, old = _timed(lambda: plant.spectral_measure(kp, kd), repeats)
        new_s, new = _timed(lambda: fast.spectral_measure(kp, kd), repeats)
        rows.append({"kp": kp, "kd": kd, "measure": old, "fast_measure": new, "rel_diff": abs(new / old - 1.0),
                     "seconds": old_s, "fast_seconds": new_s})
        log(f"  kp={kp:8.4f} kd={kd:8.4f}: |rho| {old:.9f} vs {new:.9f} (rel diff {abs(new / old - 1):.1e}); "
            f"{old_s:.3f} s -> {new_s:.3f} s CPU")
    payload = {
        "clock": "CPU time of this process (time.process_time), median of repeats",
        "states": n,
        "n_steps": plant.n_steps,
        "plant_seconds": plant_s,
        "workspace_seconds": prepare_s,
        "evaluations": rows,
        "median_seconds": statistics.median(r["seconds"] for r in rows),
        "median_fast_seconds": statistics.median(r["fast_seconds"] for r in rows),
        "max_rel_diff": max(r["rel_diff"] for r in rows),
        "platform": {"python": platform.python_version(), "numpy": np.__version__},
    }
    log(f"per evaluation: {payload['median_seconds']:.3f} s -> {payload['median_fast_seconds']:.3f} s CPU "
        f"(median), measure agrees to {payload['max_rel_diff']:.1e}")
    if tune:
        cfg = TuningConfig(target=0.3)
        tuned = {}
        for name, p in (("plant", plant), ("prepared", fast)):
            t0 = CLOCK()
            res = taguchi_tune(GainObjective(p), cfg)
            tuned[name] = {"kp": res.kp, "kd": res.kd, "spectral_radius": res.spectral_radius,
                           "evaluations": res.evaluations, "seconds": CLOCK() - t0}
            log(f"tuning with {name}: kp={res.kp:.6f} kd={res.kd:.6f} |rho|={res.spectral_radius:.9f} "
                f"({res.evaluations} evaluations, {tuned[name]['seconds']:.1f} s CPU)")
        a, b = tuned["plant"], tuned["prepared"]
        payload["tuning"] = tuned
        payload["tuned_rel_diff"] = abs(b["spectral_radius"] / a["spectral_radius"] - 1.0)
        payload["tuned_gains_equal"] = bool(abs(a["kp"] - b["kp"]) <= 1e-9 * max(1.0, a["kp"])
                                            and abs(a["kd"] - b["kd"]) <= 1e-9 * max(1.0, a["kd"]))
        log(f"tuned multiplier agrees to {payload['tuned_rel_diff']:.1e} (required {AGREEMENT:g}); "
            f"same gains: {payload['tuned_gains_equal']}")
    out.mkdir(parents=True, exist_ok=True)
    (out / "tuning_speed.json").write_text(json.dumps(payload, indent=2))
    return payload


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("results"), help="output directory (default: results)")
    ap.add_argument("--no-tune", action="store_true", help="skip the two full tunings")
    ap.add_argument("--repeats", type=int, default=3, help="timing repeats per gain pair (default 3)")
    args = ap.parse_args(argv)
    run(args.out, tune=not args.no_tune, repeats=args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
