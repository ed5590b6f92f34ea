#!/usr/bin/env python3
"""The two-link flexible arm: four-gain Taguchi with an independent check, method comparison,
mesh convergence, robust design, direct Exudyn monodromy, figures.  Writes ``results/two_link/``.

Each stage writes ``two_link_<stage>.json``; every run merges all stage files present into
``two_link.json`` (read by the study's two-link section).  Stages (``--stages``, comma separated):

``tune``     four-gain Taguchi (Hill response) at 2pi and 4pi, CPU seconds, evaluations; each tuned
             value re-checked by the streamed magnus2 product at 16384 and 32768 steps (independent);
             with ``--compare`` also Nelder-Mead and differential evolution on the same objective
``mesh``     dominant multipliers at 2, 4, 8 elements per link, uncontrolled and at the tuned gains (Hill)
``robust``   crossed-array robust design vs the nominal gains, worst case over a ``--grid``^3 noise grid
``direct``   direct Exudyn monodromy (2 elements) against Hill, uncontrolled and tuned
``figures``  gain slices (Hill response) around the tuned gains
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import resource
import time
from pathlib import Path

OMEGAS = (2, 4)
MESH = (2, 4, 8)
#: Hill harmonics per mesh (the H vs H/2 estimate is reported beside each value).
MESH_HARMONICS = {2: 24, 4: 16, 8: 12}


def cpu() -> float:
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _c(z):
    return [float(z.real), float(z.imag)]


def merge(out: Path) -> dict:
    """All stage files present, merged into ``two_link.json``; each stage's keys under ``keys[stage]``
    (the study ignores a part whose keys differ from its own: flexstab.two_link_report.fresh_parts)."""
    from flexstab.two_link_report import CACHE_PARTS

    doc: dict = {"keys": {}}
    for stage in CACHE_PARTS:
        p = out / f"two_link_{stage}.json"
        if p.exists():
            d = json.loads(p.read_text())
            doc["keys"][stage] = d.pop("keys", None)
            doc.update(d)
    (out / "two_link.json").write_text(json.dumps(doc, indent=2, default=str))
    return doc


#: The command-line arguments each stage's numbers depend on (stored in its keys: a stage file computed with
#: other arguments is started again, not extended -- its Omegas' rows would mix two settings).
STAGE_ARGS = {
    "tune": ("workers", "compare", "direct_from"),
    "mesh": (),
    "robust": ("grid", "robust_iterations", "robust_workers"),
    "direct": (),
    "figures": (),
}


def stage_keys(target: float, stage: str, args: argparse.Namespace) -> dict:
    """:func:`flexstab.two_link_report.cache_keys` (code and script SHA-256, mesh, ranges, rho_d) with the
    stage's arguments (:data:`STAGE_ARGS`)."""
    from flexstab.two_link_report import cache_keys

    return cache_keys(target, {a: getattr(args, a) for a in STAGE_ARGS[stage]})


def _same_run(stored, keys: dict) -> bool:
    """Whether ``stored`` keys (a stage file's) have every entry of ``keys``."""
    return bool(stored) and all(n in stored and stored[n] == v for n, v in keys.items())


def _resume(path: Path, keys: dict, empty: dict) -> dict:
    """A stage file to add rows to: the existing one if it was computed with ``keys``, else ``empty``."""
    if path.exists():
        d = json.loads(path.read_text())
        if d.get("keys") == keys:
            return d
        print(f"{path.name}: computed with other code or inputs: starting it again", flush=True)
    return dict(empty, keys=keys)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results/two_link")
    ap.add_argument("--stages", default="tune,mesh,robust,figures")
    ap.add_argument("--omegas", default="2,4", help="multiples of pi")
    ap.add_argument("--target", type=float, default=0.3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--compare", action="store_true", help="tune: also Nelder-Mead and differential evolution")
    ap.add_argument("--direct-from", default=None, metavar="JSON",
                    help="tune: take the Nelder-Mead / DE rows from a two_link_speed.json of the benchmark")
    ap.add_argument("--grid", type=int, default=4, help="robust: points per noise factor of the worst-case grid")
    ap.add_argument("--robust-iterations", type=int, default=4)
    ap.add_argument("--robust-workers", type=int, default=1)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    stages = [s for s in args.stages.split(",") if s]
    omegas = [int(k) for k in args.omegas.split(",")]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    from flexstab.executor import make_executor
    from flexstab.two_link import (TUNED_GAINS, TUNING_RANGES, check_multiplier, compare_direct_methods,
                                   tune_four_gains, two_link_floquet, two_link_orbit)
    from flexstab.two_link_report import cache_keys
    from linearize.constrained import linearize_orbit
    from taguchi.tuning import TuningConfig

    arms: dict = {}
    base = cache_keys(args.target)  # code and script hash, mesh, ranges, rho_d: in every stage's keys
    keys = {stage: stage_keys(args.target, stage, args) for stage in STAGE_ARGS}  # + the stage's arguments

    def arm(k, N=None):
        if (k, N) not in arms:
            o = two_link_orbit(k * math.pi, N)
            arms[(k, N)] = (o, linearize_orbit(o, 0.0, 0.0))
        return arms[(k, N)]

    def tuned_gains(k):
        p = out / "two_link_tune.json"
        if p.exists():
            d = json.loads(p.read_text())
            t = d["tune"].get(f"{k}pi") if _same_run(d.get("keys"), base) else None
            if t:
                return t["gains"]
        return list(TUNED_GAINS[k])

    if "tune" in stages:
        p = out / "two_link_tune.json"
        doc = _resume(p, keys["tune"], {"target": args.target, "tune": {}})
        for k in omegas:
            o, lin = arm(k)
            with make_executor("process", max_workers=args.workers) as ex:
                list(ex.map(abs, range(args.workers)))
                c0, t0 = cpu(), time.perf_counter()
                res = tune_four_gains(lin, args.target, orbit=o, executor=ex)
                wall = time.perf_counter() - t0
            cpu_s = cpu() - c0
            c0 = cpu()
            chk = check_multiplier(lin, o, res.gains)
            row = {"gains": list(res.gains), "rho": res.spectral_radius, "evaluations": res.evaluations,
                   "iterations": len(res.iterations), "status": res.status, "cpu_s": cpu_s, "wall_s": wall,
                   "workers": args.workers, "check": chk.to_dict(), "check_cpu_s": cpu() - c0}
            print(f"{k}pi tuned {[round(g, 5) for g in res.gains]}: Hill {res.spectral_radius:.6f}, magnus2 "
                  f"{chk.to_dict()['streamed_moduli']} ({res.evaluations} evaluations, {cpu_s:.1f} s CPU)", flush=True)
            if args.direct_from:  # Nelder-Mead / DE measured by benchmarks/two_link_speed.py --compare
                bench = {round(r["omega"] / math.pi): r for r in json.loads(Path(args.direct_from).read_text())}
                if k in bench and bench[k].get("direct"):
                    row["direct"] = bench[k]["direct"]
                    row["direct_source"] = str(args.direct_from)
                    row["benchmark"] = {key: bench[k][key] for key in ("tuning_cpu_s", "tuning_evaluations",
                                                                       "analysis_cpu_s", "cpu_seconds")}
            if args.compare:
                row["direct"] = compare_direct_methods(
                    lin, o, args.target,
                    report=lambda m, d: print(f"   {m}: {d['evaluations']} evaluations, {d['cpu_s']:.1f} s CPU, "
                                              f"{d['status']}", flush=True))
            doc["tune"][f"{k}pi"] = row
            p.write_text(json.dumps(doc, indent=2, default=str))
        merge(out)

    if "mesh" in stages:
        doc = {"mesh": {}, "keys": keys["mesh"]}
        for k in omegas:
            rows = []
            for N in MESH:
                o, lin = arm(k, N)
                row = {"elements": N, "size": lin.size, "harmonics": MESH_HARMONICS[N]}
                for label, g in (("uncontrolled", (0.0, 0.0, 0.0, 0.0)), ("tuned", tuned_gains(k))):
                    c0 = cpu()
                    fl = two_link_floquet(k * math.pi, N, g, orbit=o, lin=lin, harmonics=MESH_HARMONICS[N])
                    row[label] = {"gains": list(g), "multiplier": _c(fl.measure.dominant),
                                  "modulus": abs(fl.measure.dominant), "mode": fl.measure.mode,
                                  "hill_error_estimate": fl.measure.hill_error_estimate, "cpu_s": cpu() - c0}
                rows.append(row)
                print(f"{k}pi {N} el: uncontrolled {row['uncontrolled']['modulus']:.8f}, tuned "
                      f"{row['tuned']['modulus']:.8f}", flush=True)
                arms.pop((k, N), None)
            doc["mesh"][f"{k}pi"] = rows
            (out / "two_link_mesh.json").write_text(json.dumps(doc, indent=2, default=str))
        merge(out)

    if "robust" in stages:
        from flexstab.config import RobustSettings
        from flexstab.robust import compare_nominal_robust
        from flexstab.two_link import TwoLinkNoisePlant, two_link_noise_factors
        from taguchi.robust import RobustConfig

        p = out / "two_link_robust.json"
        doc = _resume(p, keys["robust"], {"robust": {}})
        rs = RobustSettings()
        for k in omegas:
            tcfg = TuningConfig(target=args.target, ranges=TUNING_RANGES, max_evaluations=2000)
            rcfg = RobustConfig(tuning=TuningConfig(target=args.target, ranges=TUNING_RANGES, max_evaluations=10**6),
                                noise=two_link_noise_factors(rs), sn=rs.sn, max_iterations=args.robust_iterations)
            c0, t0 = cpu(), time.perf_counter()
            # serial by default: every noise value's orbit is then computed once (a pool computes it per worker)
            with make_executor("process", max_workers=args.robust_workers) as ex:
                cmp = compare_nominal_robust(TwoLinkNoisePlant(k * math.pi), tcfg, rcfg, grid_points=args.grid,
                                             executor=ex if args.robust_workers > 1 else None)
            d = cmp.to_dict()
            d["cpu_s"], d["wall_s"] = cpu() - c0, time.perf_counter() - t0
            doc["robust"][f"{k}pi"] = d
            p.write_text(json.dumps(doc, indent=2, default=str))
            print(f"{k}pi robust: nominal worst {d['nominal']['worst']:.5f} (nominal {d['nominal']['nominal']:.5f}), "
                  f"robust worst {d['robust']['check']['worst']:.5f} (nominal {d['robust']['check']['nominal']:.5f}); "
                  f"improvement {d['worst_case_improvement_percent']:.2f} %, {d['cpu_s']:.0f} s CPU", flush=True)
        merge(out)

    if "direct" in stages:
        from mbs_models.builtin.two_link import build
        from stability.gains import Gains
        from validation.direct_monodromy import direct_monodromy

        doc = {"direct": {}, "keys": keys["direct"]}
        for k in omegas:
            o, lin = arm(k)
            rows = []
            for label, g in (("uncontrolled", [0.0, 0.0, 0.0, 0.0]), ("tuned", tuned_gains(k))):
                fl = two_link_floquet(k * math.pi, None, g, orbit=o, lin=lin)
                pd = Gains.from_interleaved(g)
                dm = direct_monodromy(build, k * math.pi, o.q[0], o.q_t[0], o.torque, kp=list(pd.kp),
                                      kd=list(pd.kd), elements=2)
                dd = dm.nearest(fl.measure.dominant)
                rows.append({"case": label, "gains": list(g), "hill": _c(fl.measure.dominant), "direct": _c(dd),
                             "difference": float(abs(fl.measure.dominant - dd)), "direct_defect": dm.defect,
                             "direct_seconds": dm.wall_time})
                print(f"{k}pi {label}: Hill {abs(fl.measure.dominant):.6f}, direct {abs(dd):.6f}", flush=True)
            doc["direct"][f"{k}pi"] = rows
        (out / "two_link_direct.json").write_text(json.dumps(doc, indent=2, default=str))
        merge(out)

    if "figures" in stages:
        from flexstab.two_link import gain_slices_hill, plot_gain_slices

        doc = {"figures": {}, "keys": keys["figures"]}
        for k in omegas:
            o, lin = arm(k)
            g = tuned_gains(k)
            sl = gain_slices_hill(lin, o, g, points=7)
            plot_gain_slices(sl, out / f"two_link_slices_{k}pi.png", target=args.target)
            (out / f"two_link_slices_{k}pi.json").write_text(json.dumps(sl.to_dict()))
            doc["figures"][f"slices_{k}pi"] = f"two_link_slices_{k}pi.png"
        (out / "two_link_figures.json").write_text(json.dumps(doc, indent=2))
        merge(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
