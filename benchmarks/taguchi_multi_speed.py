#!/usr/bin/env python3
"""Taguchi over 2 x n_drives gains against Nelder-Mead and differential evolution.

The same problem, target and tolerance (``|y - rho_d| <= 1e-3 rho_d``) for the
three methods; every method stops at its first evaluation inside the
tolerance, so the evaluation counts compare directly.  Problems:

``bowl4``
    ``y = rho_d + sum a_i (g_i - c_i)^2`` in 4 factors: one solution point
    (the hardest case for a level-set search, the easiest for a minimiser).
``levelset4``
    ``y = exp(-(g . w)) + 0.05 sin(g_1 / 7) cos(g_3 / 5)``: the target is a
    3-dimensional surface in the 4 gains, as for the real Floquet problem.
``reduced``
    The paper's single link (reduced model, two gains) at the four Table 3
    cases.

Wall times are serial in this process (the model-free objectives cost
microseconds; the Floquet evaluations of ``reduced`` a few ms).  Writes
``taguchi_multi_speed.json`` to ``--out``.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

RHO_D = 0.3


class Bowl:
    def __init__(self):
        self.c = np.array([12.3, 7.7, 21.1, 3.3])
        self.a = 1.0 / np.array([40.0, 40.0, 40.0, 40.0]) ** 2

    def __call__(self, g):
        return RHO_D + float(np.sum(self.a * (np.asarray(g) - self.c) ** 2))


class LevelSet:
    def __init__(self):
        self.w = np.array([0.02, 0.05, 0.01, 0.08])

    def __call__(self, g):
        g = np.asarray(g, dtype=float)
        return float(math.exp(-g @ self.w) + 0.05 * math.sin(g[0] / 7) * math.cos(g[2] / 5) + 0.05)


def _run(objective, cfg, label, methods):
    from taguchi.direct import direct_tune
    from taguchi.tuning import taguchi_tune

    rows = []
    t0 = time.perf_counter()
    res = taguchi_tune(objective, cfg)
    rows.append({"problem": label, "method": f"taguchi ({res.array})", "evaluations": res.evaluations,
                 "time_s": time.perf_counter() - t0, "converged": res.converged,
                 "spectral_radius": res.spectral_radius, "gains": list(res.gains)})
    for m in methods:
        d = direct_tune(objective, cfg, m)
        rows.append({"problem": label, "method": m, "evaluations": d.evaluations, "time_s": d.elapsed,
                     "converged": d.converged, "spectral_radius": d.spectral_radius, "gains": list(d.gains)})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results")
    ap.add_argument("--quick", action="store_true", help="skip differential evolution")
    args = ap.parse_args(argv)
    from mbs_models.reduced import ReducedModel
    from taguchi.tuning import GainObjective, TuningConfig

    from taguchi.arrays import array_for

    array_for(4, 3)  # load and check the array catalogue before any clock starts
    methods = ["nelder-mead"] if args.quick else ["nelder-mead", "differential-evolution"]
    rows = []
    four = TuningConfig(target=RHO_D, ranges=((0.0, 40.0),) * 4, max_evaluations=20000)
    rows += _run(Bowl(), four, "bowl4", methods)
    rows += _run(LevelSet(), four, "levelset4", methods)
    for k, rho_d in [(2, 0.3), (4, 0.3), (6, 0.3), (8, 0.4)]:
        cfg = TuningConfig(target=rho_d, max_evaluations=2000)
        rows += _run(GainObjective(ReducedModel(omega=k * math.pi)), cfg, f"reduced {k}pi", methods)
    print(f"{'problem':<14} {'method':<24} {'evals':>6} {'time s':>8} {'conv':>5} {'max|rho|':>10}")
    for r in rows:
        print(f"{r['problem']:<14} {r['method']:<24} {r['evaluations']:>6d} {r['time_s']:>8.3f} "
              f"{str(r['converged']):>5} {r['spectral_radius']:>10.6f}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "taguchi_multi_speed.json").write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
