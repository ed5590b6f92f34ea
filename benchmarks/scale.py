#!/usr/bin/env python3
"""Scale of the generic path: orbit, linearisation and Floquet of the single link at 4 ... 64 elements.

For each mesh, in a fresh subprocess (so that each mesh's
peak memory is its own): the periodic orbit (:func:`linearize.periodic_orbit.find_orbit`,
``solver="auto"``: structured Newton above the threshold), the constraint-correct
linearisation with the Table 3 gains (:func:`linearize.constrained.linearize_orbit`),
the dense Floquet multipliers (:func:`stability.floquet`, ``magnus2``, as
:func:`linearize.analysis.analyze` runs it) and the dominant ones matrix-free
(:func:`stability.implicit.implicit_floquet`, same propagator).  ``--frame modal`` propagates in
the frozen-modal coordinates of :mod:`stability.modal` (its basis is a stage of its own,
shared by both Floquet methods) and runs the dense Floquet as ``analyze()`` does:
Richardson-extrapolated, from ``N, N/2, N/4`` steps, or with ``N`` divisible by 9 from
``N, N/3, N/9`` where the coarser solves are formed from the ``N``-step factors (the
``N/3`` midpoint rule is the cubes of every third factor).  The dense solve streams its
sub-interval propagators in chunks (memory O(n^2) in the step count).  Stage limits
(``--floquet-limit``) are CPU seconds.  Per stage: wall and CPU
seconds (CPU is the honest figure on a shared machine) and the peak of numpy /
Python allocations (``tracemalloc``, with ``--trace-memory`` only: it triples the CPU time
of the allocation-heavy orbit stage); per mesh the peak resident set size of the
process (``ru_maxrss``, Exudyn's C++ memory included).  The growth exponent of
each stage is the least-squares slope of log(CPU seconds) against log(elements).

Usage::

    python3 benchmarks/scale.py --frame modal --steps 144   # 4 ... 64, writes results/scale.json
    python3 benchmarks/scale.py --elements 4 8 --steps 510  # model coordinates
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import signal
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: Table 3 gains at Omega = 2 pi (paper) and the case.
KP, KD, OMEGA = 37.1617, 29.2410, 2.0 * math.pi
def estimate_covers(accuracy: str) -> str:
    """What the dense error estimate covers with ``accuracy`` (recorded in the JSON and the table)."""
    from stability.floquet import DOMINANT_BAND, DOMINANT_SAFETY, ESTIMATE_FLOOR

    return {"moduli": f"every modulus >= {ESTIMATE_FLOOR:g} of the largest",
            "multipliers": f"every multiplier (modulus and phase) >= {ESTIMATE_FLOOR:g} of the largest",
            "dominant": f"the spectral radius and every modulus within {DOMINANT_BAND:g} of it or whose error "
                        f"interval x{DOMINANT_SAFETY:g} reaches its one (stability.floquet.dominant_mask)"}[accuracy]


_ACC_MARK = {"moduli": "", "dominant": " dom."}
STAGES = ("orbit", "linearization", "modal_basis", "floquet_dense", "floquet_implicit")


class StageTimeout(Exception):
    """A stage exceeded its time limit."""


def _alarm(signum, frame):
    raise StageTimeout()


class _Stage:
    def __init__(self, out: dict, name: str, limit: float = 0.0) -> None:
        self.out, self.name, self.limit = out, name, limit

    def __enter__(self):
        if self.limit > 0:
            # a limit on this process's CPU time (SIGPROF), not wall time: on a loaded shared
            # machine the wall clock runs 3-7x the CPU time
            signal.signal(signal.SIGPROF, _alarm)
            signal.setitimer(signal.ITIMER_PROF, self.limit)
        if tracemalloc.is_tracing():
            tracemalloc.reset_peak()
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        signal.setitimer(signal.ITIMER_PROF, 0)
        self.out[self.name] = {
            "wall_s": time.perf_counter() - self.w,
            "cpu_s": time.process_time() - self.c,
            "python_peak_mb": tracemalloc.get_traced_memory()[1] / 2**20 if tracemalloc.is_tracing() else None,
            "ok": exc[0] is None,
        }
        if exc[0] is StageTimeout:
            self.out[self.name]["error"] = f"not finished within {self.limit:.0f} s CPU"
            return True  # recorded as not finished; the next stages run
        if exc[0] is not None and self.name.startswith("floquet"):
            self.out[self.name]["error"] = " ".join(f"{exc[0].__name__}: {exc[1]}".split())[:300]
            return True  # a Floquet method that cannot run is a result; the other one still runs
        return False


def _cplx(z) -> list:
    return [float(z.real), float(z.imag)]


def worker(elements: int, samples: int, n_steps: int, dense: bool, implicit: bool, k: int,
           floquet_limit: float = 0.0, frame: str = "model", extrapolate: bool = True,
           implicit_limit: float | None = None, trace_memory: bool = False, rtol: float | None = None,
           accuracy: str = "moduli", check: bool = False, collapse: bool = True) -> dict:
    """One mesh: all stages in this process; returns the record."""
    import numpy as np

    from linearize.analysis import UNDAMPED_TOLERANCE
    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from stability import floquet
    from stability.implicit import implicit_floquet

    if trace_memory:
        tracemalloc.start()  # per-stage Python peaks; slows allocation-heavy stages (the orbit: ~3x CPU)
    rec: dict = {"elements": elements, "samples": samples, "n_steps": n_steps, "frame": frame, "collapse": collapse,
                 "extrapolate": bool(extrapolate and frame == "modal"), "rtol": rtol,
                 "accuracy": accuracy, "check": bool(check), "stages": {}}
    st = rec["stages"]
    with _Stage(st, "orbit"):
        orbit = find_orbit("single-link", OMEGA, samples=samples, elements=elements)
    rec.update(ode2=orbit.size, orbit_residual=float(orbit.residual), orbit_tolerance=float(orbit.tolerance),
               shooting_residual=float(orbit.shooting_residual), newton_iterations=int(orbit.iterations))
    with _Stage(st, "linearization"):
        lin = linearize_orbit(orbit, KP, KD)
    rec["states"] = 2 * int(lin.size)
    system = lin
    if frame == "modal":
        from stability.modal import modal_system

        with _Stage(st, "modal_basis"):
            system = modal_system(lin)  # the nested frozen-modal frames analyze() uses
        rec["modal_condition"] = float(system.condition)
        frames, inner = [], system
        while hasattr(inner, "clusters"):  # innermost frame first
            frames.append({"largest_cluster": int(max(inner.clusters)), "clusters": len(inner.clusters),
                           "method": inner.method})
            inner = inner.original
        rec["modal_frames"] = frames[::-1]  # outermost (first) frame first
    dense_mult = None
    res = None
    if dense:
        with _Stage(st, "floquet_dense", floquet_limit):
            if frame == "modal":
                from stability.modal import modal_floquet

                # as linearize.analysis.analyze runs it: Richardson-extrapolated from N, N/2, N/4
                # --rtol: the step count chosen from the extrapolated estimate (72, 144/216/288, ...)
                steps = None if (rtol is not None and extrapolate) else n_steps
                opts = {"rtol": rtol} if steps is None else {}
                res = modal_floquet(lin, basis=system, method="magnus2", n_steps=steps, accuracy=accuracy, check=check,
                                    **opts, extrapolate=extrapolate, collapse=collapse)
            else:
                res = floquet(system, method="magnus2", n_steps=n_steps, accuracy=accuracy)
    if dense and res is not None:
        dense_mult = np.asarray(res.multipliers)
        damped = [z for z in dense_mult if abs(abs(z) - 1.0) >= UNDAMPED_TOLERANCE]
        rec["dense"] = {"spectral_radius": float(res.spectral_radius), "dominant": _cplx(dense_mult[0]),
                        "dominant_damped": _cplx(damped[0]) if damped else None,
                        "error_estimate": float(res.error_estimate), "n_steps": int(res.n_steps),
                        # what error_estimate certifies (stability.floquet.ACCURACIES / dominant_mask)
                        "estimate_covers": estimate_covers(res.accuracy)
                        + ("; nested estimate and a non-nested check solve at 9N/8 steps" if check else ""),
                        "n_evaluations": int(res.n_evaluations),
                        "liouville_residual": float(res.liouville_residual),
                        "top": [_cplx(z) for z in dense_mult[:k]]}
    imp = None
    if implicit:
        with _Stage(st, "floquet_implicit", floquet_limit if implicit_limit is None else implicit_limit):
            imp = implicit_floquet(system, k=k, n_steps=n_steps, method="magnus2")
    if implicit and imp is not None:
        mult = np.asarray(imp.multipliers)
        rec["implicit"] = {"dominant": _cplx(mult[0]), "top": [_cplx(z) for z in mult],
                           "certified": [bool(c) for c in imp.certified],
                           "residuals": [float(r) for r in imp.residuals],
                           "error_estimate": float(imp.error_estimate), "matvecs": int(imp.n_matvecs)}
        if dense_mult is not None:
            # each certified implicit multiplier against the nearest dense one
            diffs = [float(np.min(np.abs(dense_mult - z))) for z, c in zip(mult, imp.certified) if c]
            rec["implicit"]["max_diff_to_dense"] = max(diffs) if diffs else math.nan
            rec["implicit"]["n_certified"] = len(diffs)
    rec["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    # the pipeline as analyze() runs it: orbit + linearisation (+ modal basis) + dense Floquet
    needed = ("orbit", "linearization") + (("modal_basis",) if frame == "modal" else ()) + ("floquet_dense",)
    pipeline = [st[s] for s in needed if s in st and "error" not in st[s]]
    rec["pipeline_complete"] = len(pipeline) == len(needed)
    rec["total_cpu_s"] = sum(v["cpu_s"] for v in pipeline)
    rec["total_wall_s"] = sum(v["wall_s"] for v in pipeline)
    return rec


def growth_exponents(records: list) -> dict:
    """Least-squares slope of log(CPU s) vs log(elements) per stage (meshes where it ran)."""
    import numpy as np

    out = {}
    for stage in STAGES + ("total",):
        xs, ys = [], []
        for r in records:
            if stage == "total":
                v = r.get("total_cpu_s") if r.get("pipeline_complete") else None
            else:
                rec = r.get("stages", {}).get(stage, {})
                v = None if "error" in rec else rec.get("cpu_s")
            if v and v > 0:
                xs.append(math.log(r["elements"]))
                ys.append(math.log(v))
        out[stage] = float(np.polyfit(xs, ys, 1)[0]) if len(xs) >= 2 else math.nan
    return out


def _fmt(x, spec=".2f") -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def _cell(st: dict, stage: str) -> str:
    v = st.get(stage)
    if v is None:
        return "not run"
    if "error" in v:
        e = v["error"]
        return "refused (memory)" if "GB of work arrays" in e else ("> limit" if "not finished" in e else "failed")
    steps = f" [{v['n_steps']} steps]" if "n_steps" in v else ""
    return f"{v['cpu_s']:.2f}{steps}"


def markdown(records: list, exps: dict) -> str:
    cols = ["elements", "ODE2 / states", "orbit CPU s (wall)", "lin. CPU s", "modal basis CPU s",
            "Floquet dense CPU s", "Floquet implicit CPU s", "pipeline CPU s (wall)", "peak RSS MB",
            "spectral radius (est.)", "largest off the unit circle", "modulus",
            "implicit: certified, max diff to dense"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in records:
        if "error" in r:
            lines.append(f"| {r['elements']} | failed: {r['error']} |" + " |" * (len(cols) - 2))
            continue
        st = r["stages"]
        d = r.get("dense", {})
        dom = d.get("dominant_damped")
        total = f"{r['total_cpu_s']:.2f} ({r['total_wall_s']:.2f})" + ("" if r.get("pipeline_complete") else " no Floquet")
        imp = r.get("implicit", {})
        imp_cell = (f"{imp.get('n_certified', sum(imp.get('certified', [])))}/{len(imp.get('certified', []))}, "
                    f"{_fmt(imp.get('max_diff_to_dense'), '.1e')}") if imp else "—"
        lines.append(
            f"| {r['elements']} | {r['ode2']} / {r['states']} | {st['orbit']['cpu_s']:.2f} ({st['orbit']['wall_s']:.2f}) | "
            f"{st['linearization']['cpu_s']:.2f} | {_cell(st, 'modal_basis') if 'modal_basis' in st else '—'} | "
            f"{_cell(st, 'floquet_dense')} | {_cell(st, 'floquet_implicit')} | "
            f"{total} | {r['peak_rss_mb']:.0f} | "
            + (f"{d['spectral_radius']:.9f} ({d['error_estimate']:.0e}{_ACC_MARK.get(r.get('accuracy'), '')}"
                f"{' +chk' if r.get('check') else ''})"
               if d else "—") + " | "
            + (f"{dom[0]:+.8f}{dom[1]:+.8f}i | {math.hypot(*dom):.8f}" if dom else "— | —")
            + f" | {imp_cell} |")
    lines.append("")
    used = sorted({r.get("accuracy", "moduli") for r in records if "error" not in r})
    lines.append("Estimate (est.) certifies: " + "; ".join(f"{a}{_ACC_MARK.get(a, '')}: {estimate_covers(a)}"
                                                         for a in used))
    lines.append("")
    lines.append("Growth exponent p (CPU s ~ elements^p, least squares over the meshes where the stage finished): "
                 + ", ".join(f"{s} {_fmt(v)}" for s, v in exps.items()))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, nargs="+", default=[4, 8, 16, 32, 64])
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--steps", type=int, default=510,
                    help="magnus2 sub-intervals (a multiple of 3: the estimate comes from the same factors)")
    ap.add_argument("--frame", choices=("model", "modal"), default="model",
                    help="propagate in the model's coordinates or the frozen-modal ones (stability.modal)")
    ap.add_argument("--no-extrapolate", action="store_true",
                    help="modal frame: plain N-step solve with its own estimate instead of analyze()'s "
                         "Richardson extrapolation from N, N/2, N/4")
    ap.add_argument("--rtol", type=float, default=None,
                    help="modal frame, extrapolated: choose the dense step count from the estimate (<= rtol) "
                         "instead of --steps (stability.modal.modal_floquet with n_steps=None)")
    ap.add_argument("--accuracy", choices=("moduli", "dominant"), default="moduli",
                    help="what the dense estimate (and --rtol's step choice) covers: every modulus >= 1e-6 of "
                         "the largest, or the spectral radius and the multipliers that could be it "
                         "(stability.floquet.dominant_mask)")
    ap.add_argument("--check", action="store_true",
                    help="modal frame, extrapolated: add the non-nested check solve (9N/8 steps) to the estimate "
                         "(stability.modal.modal_floquet(check=True))")
    ap.add_argument("--k", type=int, default=6, help="multipliers of the implicit method")
    ap.add_argument("--dense-max", type=int, default=64, help="largest mesh for the dense Floquet")
    ap.add_argument("--no-implicit", action="store_true")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per mesh")
    ap.add_argument("--floquet-limit", type=float, default=300.0,
                    help="CPU seconds per Floquet stage before it is recorded as not finished")
    ap.add_argument("--trace-memory", action="store_true",
                    help="per-stage peak of Python allocations (tracemalloc: inflates the CPU times)")
    ap.add_argument("--implicit-limit", type=float, default=None,
                    help="CPU seconds for the implicit stage (default: --floquet-limit)")
    ap.add_argument("--out", default=str(ROOT / "results" / "scale.json"))
    ap.add_argument("--no-collapse", action="store_true",
                    help="modal frame: propagate the nested frames one by one (two solves per time) instead of "
                         "in their composite basis")
    ap.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--dense", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker is not None:
        rec = worker(args.worker, args.samples, args.steps, bool(args.dense), not args.no_implicit, args.k,
                     args.floquet_limit, args.frame, not args.no_extrapolate, args.implicit_limit,
                     args.trace_memory, args.rtol, args.accuracy, args.check, not args.no_collapse)
        print(json.dumps(rec))
        return 0
    records = []
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for e in args.elements:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(e), "--samples", str(args.samples),
               "--steps", str(args.steps), "--k", str(args.k), "--dense", str(int(e <= args.dense_max)),
               "--floquet-limit", str(args.floquet_limit), "--frame", args.frame, "--accuracy", args.accuracy]
        if args.no_extrapolate:
            cmd.append("--no-extrapolate")
        if args.check:
            cmd.append("--check")
        if args.rtol is not None:
            cmd += ["--rtol", repr(args.rtol)]
        if args.implicit_limit is not None:
            cmd += ["--implicit-limit", str(args.implicit_limit)]
        if args.trace_memory:
            cmd.append("--trace-memory")
        if args.no_implicit:
            cmd.append("--no-implicit")
        if args.no_collapse:
            cmd.append("--no-collapse")
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout, env=env)
            if p.returncode != 0:
                last = (p.stderr.strip().splitlines() or ["no output"])[-1]
                rec = {"elements": e, "error": last}
            else:
                rec = json.loads(p.stdout.strip().splitlines()[-1])
        except subprocess.TimeoutExpired:
            rec = {"elements": e, "error": f"timeout after {args.timeout:.0f} s"}
        records.append(rec)
        print(f"elements {e}: " + (rec["error"] if "error" in rec else
                                   f"total CPU {rec['total_cpu_s']:.2f} s, wall {rec['total_wall_s']:.2f} s, "
                                   f"peak RSS {rec['peak_rss_mb']:.0f} MB"), file=sys.stderr, flush=True)
    ok = [r for r in records if "error" not in r]
    exps = growth_exponents(ok)
    table = markdown(records, exps)
    print(table)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"case": {"model": "single-link", "omega": OMEGA, "kp": KP, "kd": KD,
                                        "samples": args.samples, "n_steps": args.steps, "frame": args.frame,
                                        "accuracy": args.accuracy, "rtol": args.rtol,
                                        "check": args.check},
                               "records": records, "growth_exponents": exps, "table": table}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
