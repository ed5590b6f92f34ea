#!/usr/bin/env python3
"""The two-link flexible arm (issue 11): Floquet at 2pi and 4pi, mesh convergence, direct check,
four-gain Taguchi, figures.  Writes ``results/two_link/`` (JSON + PNG + report.md).

Stages (``--stages``, comma separated; default all):

``floquet``   orbit + linearisation + labelled multipliers, uncontrolled, at the default mesh
``mesh``      dominant damped multipliers at 2, 4, 8 elements per link (uncontrolled and tuned gains)
``tune``      four-gain Taguchi to rho_d at both Omega, re-checked with an adaptive Floquet run
``direct``    direct Exudyn monodromy (2 elements) against the generic path, uncontrolled and tuned
``figures``   poses over one period, Floquet mode pictures (two-link and single link), gain slices
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import time
from pathlib import Path

import numpy as np

OMEGAS = (2, 4)
#: magnus2 sub-intervals: in the tuning loop, and the re-checks (the engine's memory
#: limit allows 8192 for the 40 x 40 system of 2 elements per link, 2048 for 4, 1024 for 8).
LOOP_STEPS = 2048
CHECK_STEPS = {2: (4096, 8192), 4: (1024, 2048), 8: (512, 1024)}


def _opts(n):
    return {"method": "magnus2", "n_steps": n, "error_estimate": False}


def _mu(z):
    return [float(np.real(z)), float(np.imag(z))]


def _labelled(res, count=10):
    rows = []
    for mu, m in list(zip(res.floquet.multipliers, res.modes)):
        if m["undamped"]:
            continue
        rows.append({"multiplier": _mu(mu), "modulus": float(abs(mu)), "mode": m["mode"], "group": m["group"],
                     "frequency_hz": m["frequency_hz"]})
        if len(rows) >= count:
            break
    undamped = sum(1 for m in res.modes if m["undamped"])
    return {"damped": rows, "undamped_count": undamped, "dominant": _mu(res.dominant_multiplier),
            "dominant_modulus": float(abs(res.dominant_multiplier)), "orbit_residual": res.orbit_residual,
            "shooting_residual": float(res.orbit.shooting_residual), "timings": dict(res.timings)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results/two_link")
    ap.add_argument("--stages", default="floquet,mesh,tune,direct,figures")
    ap.add_argument("--target", type=float, default=0.3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--elements", type=int, default=None, help="default mesh (default: the model file's)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    stages = set(args.stages.split(","))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    from flexstab.executor import make_executor
    from flexstab.two_link import MODEL, LabelledGainObjective, gain_slices, plot_gain_slices, tune_four_gains
    from linearize.analysis import analyze
    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from mbs_models.builtin.two_link import DEFAULT_ELEMENTS, build
    from mbs_models.model_file import builtin_model
    from stability import floquet

    N0 = args.elements or DEFAULT_ELEMENTS
    report: dict = {"model": MODEL, "default_elements": N0, "target": args.target}
    orbits: dict = {}
    lins: dict = {}

    def orbit(k, N):
        if (k, N) not in orbits:
            orbits[(k, N)] = find_orbit(builtin_model(MODEL, elements=N), k * math.pi)
            lins[(k, N)] = linearize_orbit(orbits[(k, N)], 0.0, 0.0)
        return orbits[(k, N)], lins[(k, N)]

    tuned: dict = {}
    gains_file = out / "tuned_gains.json"
    if gains_file.exists():
        tuned = {int(k): v for k, v in json.loads(gains_file.read_text()).items()}

    if "floquet" in stages:
        report["floquet"] = {}
        for k in OMEGAS:
            o, _ = orbit(k, N0)
            res = analyze(builtin_model(MODEL, elements=N0), k * math.pi, orbit=o, n_steps=LOOP_STEPS)
            report["floquet"][f"{k}pi"] = {"uncontrolled": _labelled(res)}
            print(f"{k}pi uncontrolled: dominant {abs(res.dominant_multiplier):.6f} ({res.modes[0]['mode']})")

    if "tune" in stages:
        report["tune"] = {}
        with make_executor("process", max_workers=args.workers) as ex:
            for k in OMEGAS:
                o, lin = orbit(k, N0)
                t0 = time.perf_counter()
                res = tune_four_gains(lin, args.target, orbit=o, executor=ex, floquet_options=_opts(LOOP_STEPS))
                elapsed = time.perf_counter() - t0
                g = res.gains
                checks = {n: LabelledGainObjective(lin, o, _opts(n))(g) for n in CHECK_STEPS[N0]}
                tuned[k] = list(g)
                report["tune"][f"{k}pi"] = {"gains": list(g), "names": list(res.names), "rho_loop": res.spectral_radius,
                                            "rho_checks": checks, "evaluations": res.evaluations,
                                            "iterations": len(res.iterations), "seconds": elapsed,
                                            "converged": res.converged}
                print(f"{k}pi tuned {np.round(g, 4)}: loop {res.spectral_radius:.6f}, checks {checks} "
                      f"({res.evaluations} evaluations, {elapsed:.1f} s)")
        gains_file.write_text(json.dumps(tuned))

    if "floquet" in stages and tuned:
        for k in OMEGAS:
            if k in tuned:
                o, _ = orbit(k, N0)
                g = tuned[k]
                res = analyze(builtin_model(MODEL, elements=N0), k * math.pi, orbit=o, kp=g[0::2], kd=g[1::2],
                              n_steps=LOOP_STEPS)
                report["floquet"][f"{k}pi"]["controlled"] = {"gains": g, **_labelled(res)}

    if "mesh" in stages:
        report["mesh"] = {}
        for k in OMEGAS:
            rows = []
            for N in (2, 4, 8):
                o, lin = orbit(k, N)
                row = {"elements": N}
                for label, g in (("uncontrolled", [0.0, 0.0, 0.0, 0.0]), ("controlled", tuned.get(k))):
                    if g is None:
                        continue
                    row[label] = {n: LabelledGainObjective(lin, o, _opts(n))(g) for n in CHECK_STEPS[N]}
                rows.append(row)
                print(f"{k}pi mesh {N}: {row}")
            report["mesh"][f"{k}pi"] = rows

    if "direct" in stages:
        from validation.direct_monodromy import direct_monodromy

        report["direct"] = {}
        for k in OMEGAS:
            o, lin = orbit(k, 2)
            rows = []
            for label, g in (("uncontrolled", [0.0, 0.0, 0.0, 0.0]), ("controlled", tuned.get(k))):
                if g is None:
                    continue
                dm = direct_monodromy(build, k * math.pi, o.q[0], o.q_t[0], o.torque, kp=g[0::2], kd=g[1::2],
                                      elements=2)
                from linearize.analysis import label_multipliers
                from flexstab.two_link import main_dominant

                lg = lin.with_gains(list(g[0::2]), list(g[1::2]))
                r = floquet(lg, **_opts(CHECK_STEPS[2][-1]))
                gen = main_dominant(r.multipliers, label_multipliers(lg, o, r), o.drive_names)
                dd = dm.nearest(gen)
                rows.append({"case": label, "gains": g, "generic": _mu(gen), "direct": _mu(dd),
                             "difference": float(abs(gen - dd)), "direct_defect": dm.defect,
                             "direct_seconds": dm.wall_time})
                print(f"{k}pi {label}: generic {abs(gen):.6f}, direct {abs(dd):.6f}, |diff| {abs(gen - dd):.2e}")
            report["direct"][f"{k}pi"] = rows

    if "figures" in stages:
        from flexstab.arm_figures import plot_floquet_mode, plot_poses

        figs = {}
        o, lin = orbit(2, N0)
        figs["poses_2pi"] = str(plot_poses(o, out / "two_link_poses_2pi.png"))
        for k in OMEGAS:
            o, lin = orbit(k, N0)
            g = tuned.get(k, [0.0, 0.0, 0.0, 0.0])
            res = analyze(builtin_model(MODEL, elements=N0), k * math.pi, orbit=o, kp=g[0::2], kd=g[1::2],
                          n_steps=LOOP_STEPS)
            figs[f"mode_{k}pi"] = str(plot_floquet_mode(res, out / f"two_link_mode_{k}pi.png"))
            if k in tuned:
                sl = gain_slices(lin, g, orbit=o, points=7, floquet_options=_opts(1024))
                plot_gain_slices(sl, out / f"two_link_slices_{k}pi.png", target=args.target)
                figs[f"slices_{k}pi"] = str(out / f"two_link_slices_{k}pi.png")
                (out / f"two_link_slices_{k}pi.json").write_text(json.dumps(sl.to_dict()))
        single = analyze(builtin_model("single-link", elements=8), 2 * math.pi, kp=37.1617, kd=29.2410)
        figs["single_link_mode_2pi"] = str(plot_floquet_mode(single, out / "single_link_mode_2pi.png"))
        report["figures"] = figs

    (out / "two_link.json").write_text(json.dumps(report, indent=2, default=str))
    print(f"wrote {out / 'two_link.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
