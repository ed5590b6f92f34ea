#!/usr/bin/env python3
"""Benchmark: ``flexstab floquet --model exudyn`` per Omega against the cheapest honest baselines.

For each Table 3 case (Omega = 2 pi .. 8 pi with the printed gains; default the README's
case 8 pi, ``--all`` for the four) this measures, in one run:

* **the command** as a user runs it, ``flexstab floquet --model exudyn --omega Kpi --kp KP
  --kd KD --json`` in a subprocess: wall seconds and CPU seconds (user + system of the child,
  imports of numpy, scipy and Exudyn included).  Target: <= 2 s wall per Omega on 2 cores;
* **the same command with** ``--model single-link``, the built-in model file ``exudyn`` is
  an alias of: the ratio ``exudyn / single-link`` is what the alias costs (about 1), and the
  dominant multipliers must be equal;
* with ``--scipy``, **a scipy baseline of the Floquet stage**: the monodromy of the same linearisation (orbit
  and linearisation by :func:`linearize.analysis.analyze` once in this process) by
  ``scipy.integrate.solve_ivp`` on ``Phi' = P(t) Phi``, ``Phi(0) = I`` (Radau with the exact
  block-diagonal Jacobian ``I (x) P(t)``, sparse; ``rtol`` 1e-8, ``atol`` 1e-11: ``||P||``
  reaches ~4e5 1/s, explicit methods are out of the question), CPU seconds of this process.
  Reported: its dominant (hub) multiplier beside the command's, and the ratio of the command's
  Floquet stage (``timings.floquet``, wall) to the baseline.  Off by default: the link's undamped
  axial modes (up to ~47 kHz at 8 elements) make Radau take ~1e5 steps per period at this
  tolerance -- more than ten minutes per Omega here; ``--model single-link`` is the cheapest
  honest baseline of the whole command.

Each command runs ``--repeat`` times (default 3) after one uncounted warm-up call; the median call
is reported.  CPU seconds are the figure to read on a shared machine (the wall clock also counts the other
tenants); the machine's load average is printed with the results.

Usage::

    python benchmarks/exudyn_route.py                # 8 pi (the acceptance case)
    python benchmarks/exudyn_route.py --all          # 2, 4, 6, 8 pi
    python benchmarks/exudyn_route.py --scipy        # also the scipy baseline (slow)
    python benchmarks/exudyn_route.py --json
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import subprocess
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

#: The acceptance target of one ``flexstab floquet --model exudyn`` call (wall seconds, 8 elements).
TARGET_WALL = 2.0
#: Tolerances of the scipy baseline (Radau).
SCIPY_RTOL = 1e-8
SCIPY_ATOL = 1e-11


def run_command(model: str, k: int, kp: float, kd: float) -> dict:
    """One ``flexstab floquet`` call in a subprocess: wall and CPU seconds and the JSON it printed."""
    script = shutil.which("flexstab", path=os.path.dirname(sys.executable))  # the console script a user runs
    head = [script] if script else [sys.executable, "-c", "import sys; from flexstab.cli import main; sys.exit(main())"]
    argv = head + ["floquet", "--model", model, "--omega", f"{k}pi", "--kp", f"{kp}", "--kd", f"{kd}", "--json"]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    # as on a user's machine, Python caches the bytecode of the package (the first call compiles it,
    # ~0.15 s; an environment with PYTHONDONTWRITEBYTECODE would pay that on every call)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    tic = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, env=env, check=False)
    wall = time.perf_counter() - tic
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"flexstab {' '.join(argv[len(head):])} failed ({proc.returncode}): {proc.stderr.strip()}")
    d = json.loads(proc.stdout)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "dominant_modulus": d["dominant_modulus"],
            "dominant_mode": d.get("dominant_mode"), "spectral_radius": d["spectral_radius"],
            "error_estimate": d["error_estimate"], "dominant_error_estimate": d.get("dominant_error_estimate"),
            "floquet_stage_s": d["timings"]["floquet"], "orbit_stage_s": d["timings"]["orbit"],
            "n_steps": d["n_steps"], "all_certified": d.get("all_certified")}


def median_run(model: str, k: int, kp: float, kd: float, repeat: int) -> dict:
    """:func:`run_command` ``repeat`` times: the call of median wall time, with every wall time in ``walls_s``."""
    runs = sorted((run_command(model, k, kp, kd) for _ in range(max(1, repeat))), key=lambda r: r["wall_s"])
    return dict(runs[len(runs) // 2], walls_s=[r["wall_s"] for r in runs])


def scipy_monodromy(lin) -> tuple[np.ndarray, float, int]:
    """Monodromy of ``x' = P(t) x`` by ``solve_ivp`` (Radau, sparse exact Jacobian); ``(Phi, cpu_s, nfev)``."""
    import scipy.sparse
    from scipy.integrate import solve_ivp

    n2 = 2 * lin.size
    eye = scipy.sparse.identity(n2, format="csc")

    def rhs(t, y):
        return (lin(t) @ y.reshape(n2, n2, order="F")).ravel(order="F")

    def jac(t, y):  # noqa: ARG001  (linear: the Jacobian does not depend on y)
        return scipy.sparse.kron(eye, scipy.sparse.csc_matrix(lin(t)), format="csc")

    tic = time.process_time()
    sol = solve_ivp(rhs, (0.0, lin.period), np.eye(n2).ravel(order="F"), method="Radau", jac=jac,
                    rtol=SCIPY_RTOL, atol=SCIPY_ATOL)
    cpu = time.process_time() - tic
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y[:, -1].reshape(n2, n2, order="F"), cpu, int(sol.nfev)


def scipy_baseline(k: int, kp: float, kd: float, dominant: complex) -> dict:
    """The scipy baseline of the Floquet stage on the same linearisation (see the module notes)."""
    from flexstab.config import StudyConfig
    from flexstab.options import EXUDYN_ALIAS, resolve_model_definition
    from linearize.analysis import analyze

    cfg = StudyConfig()
    definition, options = resolve_model_definition(EXUDYN_ALIAS, cfg)
    res = analyze(definition, k * math.pi, kp=kp, kd=kd, **options)
    Phi, cpu, nfev = scipy_monodromy(res.linearization)
    mu = np.linalg.eigvals(Phi)
    near = complex(mu[int(np.argmin(np.abs(mu - dominant)))])
    return {"cpu_s": cpu, "nfev": nfev, "dominant_modulus": abs(near),
            "relative_difference": abs(abs(near) - abs(dominant)) / abs(dominant)}


def main(argv=None) -> int:
    from mbs_models.paper_data import TABLE3_GAINS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--all", action="store_true", help="the four Table 3 cases (default: 8 pi)")
    ap.add_argument("--scipy", action="store_true", help="also the scipy (Radau) baseline of the Floquet stage (slow)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--repeat", type=int, default=3, help="calls per case; the median call is reported (default 3)")
    args = ap.parse_args(argv)
    cases = (2, 4, 6, 8) if args.all else (8,)
    rows = []
    run_command("exudyn", cases[0], *TABLE3_GAINS[cases[0]])  # warm-up (bytecode, disk caches): not counted
    for k in cases:
        kp, kd = TABLE3_GAINS[k]
        ex = median_run("exudyn", k, kp, kd, args.repeat)
        sl = median_run("single-link", k, kp, kd, args.repeat)
        row = {"omega_over_pi": k, "kp": kp, "kd": kd, "exudyn": ex, "single_link": sl,
               "ratio_wall_exudyn_to_single_link": ex["wall_s"] / sl["wall_s"],
               "ratio_cpu_exudyn_to_single_link": ex["cpu_s"] / sl["cpu_s"],
               "target_wall_s": TARGET_WALL, "meets_target_wall": ex["wall_s"] <= TARGET_WALL,
               "meets_target_cpu": ex["cpu_s"] <= TARGET_WALL}
        if args.scipy:
            base = scipy_baseline(k, kp, kd, complex(ex["dominant_modulus"]))
            row["scipy"] = base
            row["ratio_floquet_stage_to_scipy"] = ex["floquet_stage_s"] / base["cpu_s"]
        rows.append(row)
    out = {"load_average": list(os.getloadavg()), "cpu_count": os.cpu_count(), "rows": rows}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"load average {', '.join(f'{x:.2f}' for x in out['load_average'])} on {out['cpu_count']} cores")
    print(f"{'Omega':>6} {'exudyn wall':>12} {'cpu':>6} {'single-link wall':>17} {'cpu':>6} {'ratio':>6}"
          f" {'target':>7}   dominant |rho| (exudyn / single-link / scipy)")
    for r in rows:
        ex, sl = r["exudyn"], r["single_link"]
        sc = r.get("scipy")
        scs = f" / {sc['dominant_modulus']:.9f}" if sc else ""
        print(f"{r['omega_over_pi']:>4}pi {ex['wall_s']:>11.2f}s {ex['cpu_s']:>5.2f}s {sl['wall_s']:>16.2f}s "
              f"{sl['cpu_s']:>5.2f}s {r['ratio_cpu_exudyn_to_single_link']:>6.2f} "
              f"{'met' if r['meets_target_wall'] else 'MISSED':>7}   "
              f"{ex['dominant_modulus']:.9f} / {sl['dominant_modulus']:.9f}{scs}")
        if sc:
            print(f"       Floquet stage {ex['floquet_stage_s']:.2f} s ({ex['n_steps']} steps, estimate "
                  f"{ex['dominant_error_estimate']:.1e}) vs scipy Radau {sc['cpu_s']:.2f} s CPU ({sc['nfev']} "
                  f"evaluations): ratio {r['ratio_floquet_stage_to_scipy']:.3f}; dominant multipliers "
                  f"{sc['relative_difference']:.1e} apart")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
