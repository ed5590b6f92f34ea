"""Benchmark: the default Floquet method vs the best ``scipy.integrate.solve_ivp`` baseline.

For the 8 cases of the paper's Tables 2 and 3 (p. 489: uncontrolled manipulator
at Omega = 2pi..8pi, and the same with Table 3's printed PD gains) this measures,
in one run,

* the time per evaluation of ``stability.floquet(model)`` as called by default
  (``magnus6``, adaptive refinement, rtol 1e-9 on the moduli): median of >= 5
  repeats (and, for information, with ``accuracy="multipliers"``, which also
  certifies the phases);
* the time of the fastest scipy baseline on the matrix ODE
  ``Phi' = P(t) Phi``, ``Phi(0) = I`` (16 states) with a *lean* ``P(t)``: the
  paper's Eqs. (21)-(25) written plainly for one scalar ``t`` (4x4 numpy, no
  package code), the fastest of ``solve_ivp``'s DOP853, RK45, LSODA, BDF, Radau and
  ``odeint`` (implicit ones with the exact Jacobian ``kron(P, I)``), each at the loosest ``rtol`` in
  1e-6 .. 1e-12 (``atol = 1e-3 rtol``) that reaches <= 1e-8 relative error on
  every modulus >= 1e-6 of the largest;

Times are CPU seconds of this process (``time.process_time``; everything is
single-threaded with ``OPENBLAS_NUM_THREADS=1``), so that other tenants of a
shared machine do not decide the ratio.  Both sides are timed *interleaved*: after
the search, each round times a batch of default calls and one run of every
baseline finalist (each accepted method within :data:`FINALIST_FACTOR` of the
fastest one found; the timed runs use a plain right-hand side, the clock is read
only in the search), one sample per side and round (the default's is the mean of a
batch of calls), and each side's figure is the minimum of its samples (the usual
estimator for deterministic CPU-bound code: noise only adds time), so a slow spell
of the machine hits both sides alike and both have the same number of samples (at least
7 rounds a case, more until they span 1.5 CPU seconds: a cheap case's rounds would
otherwise fit inside one slow spell).  Accuracy is checked against a
reference computed once per case, independent of the package's Floquet code: the
lean ``P(t)`` integrated by DOP853 at rtol 1e-13, atol 1e-16 (default), or with
``--reference paper`` the paper's procedure at rtol 1e-11 (DOP853, or Radau where
P is stiff), whose own error (~1e-11 on the uncontrolled cases) exceeds the
default's: the error column then shows the reference's error, not the method's.  A baseline run already slower than
``FINALIST_FACTOR`` times the best accepted one is abandoned (tighter tolerances
are only slower), which keeps the search affordable without changing its outcome.

Usage::

    python benchmarks/floquet_speed.py            # full run (~1 min: references, baselines, timing rounds)
    python benchmarks/floquet_speed.py --quick    # 2 cases, 2 tolerances
    python benchmarks/floquet_speed.py --out results
    FLEXSTAB_NUMBA=0 python benchmarks/floquet_speed.py   # the numpy path of small systems

Writes ``<out>/floquet_speed.json`` (default ``results/``).
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import scipy
from scipy.integrate import odeint, solve_ivp

from mbs_models.parameters import ManipulatorParameters
from mbs_models.reduced import PAPER_MODE_CONSTANTS, ReducedModel
from stability import floquet
from stability.reference import ReferenceOptions, paper_monodromy

#: (label, Omega/pi, kp, kd): paper Table 2 (uncontrolled) and Table 3 (printed gains), p. 489.
CASES = [
    ("T2 2pi", 2, 0.0, 0.0),
    ("T2 4pi", 4, 0.0, 0.0),
    ("T2 6pi", 6, 0.0, 0.0),
    ("T2 8pi", 8, 0.0, 0.0),
    ("T3 2pi", 2, 37.1617, 29.2410),
    ("T3 4pi", 4, 28.7617, 11.7501),
    ("T3 6pi", 6, 22.2666, 6.7208),
    ("T3 8pi", 8, 23.0147, 6.8628),
]
QUICK_CASES = ["T2 8pi", "T3 8pi"]

#: solve_ivp methods, and "odeint" (scipy.integrate.odeint: LSODA driven from Fortran, less Python per step)
IVP_METHODS = ["DOP853", "RK45", "LSODA", "BDF", "Radau", "odeint"]
IMPLICIT = {"Radau", "BDF", "LSODA"}
RTOLS = [1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12]
QUICK_RTOLS = [1e-9, 1e-11]
#: atol = ATOL_FACTOR * rtol (the entries of Phi are O(1) .. O(1e3)).
ATOL_FACTOR = 1e-3
#: Required relative accuracy on every modulus >= MODULUS_FLOOR * the largest.
TARGET = 1e-8
MODULUS_FLOOR = 1e-6
#: CPU-time cap on a single baseline run before any has been accepted.
FIRST_RUN_CAP = 300.0
#: Accepted baselines within this factor of the fastest one found in the search are all re-timed
#: in the interleaved rounds (a single search run can be slowed by the machine).
FINALIST_FACTOR = 1.5
#: Interleaved timing rounds (full run / --quick) and default calls per round: at least this many,
#: and in a full run more until the rounds of a case span MIN_SPAN CPU seconds (at most MAX_ROUNDS),
#: so that a slow spell of a shared machine does not cover every round of a cheap case.
ROUNDS, QUICK_ROUNDS = 7, 3
MIN_SPAN, MAX_ROUNDS = 1.5, 200
DEFAULT_BATCH = 15
#: Both sides are timed in CPU seconds of this (single-threaded) process: on a
#: shared machine wall time mostly measures the other tenants.
CLOCK = time.process_time
CLOCK_NAME = "CPU time of this process (time.process_time), minimum over interleaved rounds (default: batch means)"


class _Abandoned(Exception):
    pass


def lean_P(omega: float, kp: float, kd: float):
    """``t -> P(t)`` (4x4) of the paper's Eqs. (21)-(25), (32)-(33), written plainly.

    Table 1 data and the printed mode constants; no package code on the call
    path (the honest baseline's right-hand side).
    """
    p, c = ManipulatorParameters(), PAPER_MODE_CONSTANTS
    mu, l, mE, g, m = p.mass_per_length, p.length, p.tip_mass, p.gravity, p.link_mass
    M = np.array([[p.hub_inertia + mE * l**2 + m * l**2 / 3.0, mu * c.D1 + mE * l * c.X1],
                  [mu * c.D1 + mE * l * c.X1, mE * c.X1**2 + mu * c.m11]])
    Minv = np.linalg.inv(M)
    C = np.array([[p.joint_damping + kd, 0.0], [0.0, 0.0]])
    MinvC = Minv @ C
    EIk = p.bending_stiffness * c.k11_star
    a = math.pi / 2

    def P(t: float) -> np.ndarray:
        q = a + a * math.sin(omega * t)
        qd = a * omega * math.cos(omega * t)
        s = math.sin(q)
        k12 = -mE * g * c.X1 * s - mu * g * s * c.C1
        K = np.array([[-l * s * mE * g - m * g * l * s / 2.0 + kp, k12],
                      [k12, -mE * qd**2 * c.X1**2 - mu * qd**2 * c.m11 + EIk]])
        out = np.zeros((4, 4))
        out[0, 2] = out[1, 3] = 1.0
        out[2:, :2] = -Minv @ K
        out[2:, 2:] = -MinvC
        return out

    return P


@dataclass
class CaseResult:
    case: str
    omega: float
    kp: float
    kd: float
    reference_moduli: list
    reference_seconds: float
    default_ms: float
    default_repeats: int
    default_n_steps: int
    default_max_rel_error: float
    default_error_estimate: float
    multipliers_ms: float
    multipliers_n_steps: int
    multipliers_max_rel_error: float
    best_method: Optional[str]
    best_rtol: Optional[float]
    best_ms: Optional[float]
    best_max_rel_error: Optional[float]
    ratio: Optional[float]
    tried: list


def _moduli(Phi: np.ndarray) -> np.ndarray:
    return np.sort(np.abs(np.linalg.eigvals(Phi)))[::-1]


def _max_rel_error(moduli: np.ndarray, ref: np.ndarray) -> float:
    keep = ref >= MODULUS_FLOOR * ref[0]
    return float(np.max(np.abs(moduli[keep] / ref[keep] - 1.0)))


def _reference(model: ReducedModel, kind: str) -> np.ndarray:
    """Reference multipliers (complex, sorted by modulus descending)."""
    if kind == "paper":
        return floquet(model, method="paper", error_estimate=False).multipliers
    P = lean_P(model.omega, model.kp, model.kd)
    Phi, _ = paper_monodromy(P, model.period, ReferenceOptions("DOP853", rtol=1e-13, atol=1e-16))
    mu = np.linalg.eigvals(Phi)
    return mu[np.lexsort((-mu.imag, -np.abs(mu)))]


def _max_rel_multiplier_error(mult: np.ndarray, ref: np.ndarray) -> float:
    """Largest ``|mu - mu_ref| / |mu_ref|`` over the multipliers >= MODULUS_FLOOR of the largest."""
    keep = np.abs(ref) >= MODULUS_FLOOR * np.abs(ref[0])
    return float(np.max(np.abs(mult[keep] - ref[keep]) / np.abs(ref[keep])))


def _ivp_monodromy(model: ReducedModel, method: str, rtol: float, deadline: float) -> np.ndarray:
    """Phi(T) from one solve_ivp (or odeint) call on the 16-dimensional matrix ODE (row-major vec), lean P."""
    P = lean_P(model.omega, model.kp, model.kd)
    n = 4
    eye = np.eye(n)

    if math.isinf(deadline):  # a timed run: the plain right-hand side, no clock reads

        def rhs(t, y):
            return (P(t) @ y.reshape(n, n)).ravel()
    else:  # the search: abandoned past the deadline

        def rhs(t, y):
            if CLOCK() > deadline:
                raise _Abandoned
            return (P(t) @ y.reshape(n, n)).ravel()

    if method == "odeint":
        y = odeint(lambda y, t: rhs(t, y), eye.ravel(), [0.0, model.period], rtol=rtol, atol=ATOL_FACTOR * rtol,
                   mxstep=10**6, Dfun=lambda y, t: np.kron(P(t), eye))
        return y[-1].reshape(n, n)
    kwargs = {}
    if method in IMPLICIT:
        # d vec(P Phi) / d vec(Phi) = kron(P, I) for row-major vec
        kwargs["jac"] = lambda t, y: np.kron(P(t), eye)
    sol = solve_ivp(rhs, (0.0, model.period), eye.ravel(), method=method,
                    rtol=rtol, atol=ATOL_FACTOR * rtol, **kwargs)
    if not sol.success:
        raise RuntimeError(sol.message)
    return sol.y[:, -1].reshape(n, n)


def _search_baseline(model, ref, methods, rtols, log):
    """The accepted ``solve_ivp`` configurations (loosest passing ``rtol`` of each method) whose search
    run is within :data:`FINALIST_FACTOR` of the fastest: ``[(seconds, method, rtol, err)]``, fastest first."""
    accepted = []  # (seconds, method, rtol, err)
    tried = []
    for method in methods:
        for rtol in rtols:
            best = min(accepted)[0] if accepted else None
            cap = FINALIST_FACTOR * best if best is not None else FIRST_RUN_CAP
            t0 = CLOCK()
            try:
                Phi = _ivp_monodromy(model, method, rtol, t0 + cap)
            except _Abandoned:
                tried.append({"method": method, "rtol": rtol, "status": f"abandoned (> {cap:.3g} s)"})
                log(f"    {method:6s} rtol={rtol:.0e}: abandoned after {cap:.3g} s")
                break  # tighter tolerances are slower still
            except Exception as exc:  # integrator failure: record and try a tighter tolerance
                tried.append({"method": method, "rtol": rtol, "status": f"failed: {exc}"})
                continue
            dt = CLOCK() - t0
            err = _max_rel_error(_moduli(Phi), np.abs(ref))
            ok = err <= TARGET
            tried.append({"method": method, "rtol": rtol, "seconds": dt, "max_rel_error": err, "accepted": ok})
            log(f"    {method:6s} rtol={rtol:.0e}: {dt * 1e3:9.1f} ms  err={err:.1e} {'ok' if ok else ''}")
            if ok:
                accepted.append((dt, method, rtol, err))
                break  # the loosest accepted tolerance of this method
            if best is not None and dt > FINALIST_FACTOR * best:
                break
    accepted.sort()
    return [a for a in accepted if a[0] <= FINALIST_FACTOR * accepted[0][0]], tried


def _interleaved(model, finalists, rounds: int, span: float = 0.0, **options):
    """CPU time of ``floquet(model, **options)`` and of each baseline finalist, timed in ``rounds``
    interleaved rounds: one sample per side and round (for the default the mean of a batch of
    :data:`DEFAULT_BATCH` calls, a run of its own length comparable to one baseline run), each side's
    figure the minimum of its samples; ``rounds`` rounds at least, more (up to :data:`MAX_ROUNDS`)
    until they span ``span`` CPU seconds.  Returns ``(default seconds, default calls, last result,
    [finalist seconds])``."""
    res = floquet(model, **options)  # warm-up
    default, calls = math.inf, 0
    base = [math.inf] * len(finalists)
    start, done = CLOCK(), 0
    while done < rounds or (CLOCK() - start < span and done < MAX_ROUNDS):
        done += 1
        t0 = CLOCK()
        for _ in range(DEFAULT_BATCH):
            res = floquet(model, **options)
        default = min(default, (CLOCK() - t0) / DEFAULT_BATCH)
        calls += DEFAULT_BATCH
        for i, (_, method, rtol, _) in enumerate(finalists):
            t0 = CLOCK()
            _ivp_monodromy(model, method, rtol, math.inf)
            base[i] = min(base[i], CLOCK() - t0)
    return default, calls, res, base


def run(quick: bool = False, out: Path = Path("results"), reference: Optional[str] = None,
        verbose: bool = True) -> dict:
    log = (lambda s: print(s, flush=True)) if verbose else (lambda s: None)
    cases = [c for c in CASES if c[0] in QUICK_CASES] if quick else CASES
    rtols = QUICK_RTOLS if quick else RTOLS
    reference = reference or "dop853"
    log(f"timing: {CLOCK_NAME}")
    results = []
    for label, k, kp, kd in cases:
        model = ReducedModel(k * math.pi, kp, kd)
        log(f"{label}: reference ({reference}) ...")
        t0 = CLOCK()
        ref = _reference(model, reference)
        ref_s = CLOCK() - t0
        finalists, tried = _search_baseline(model, ref, IVP_METHODS, rtols, log)
        d_s, d_rep, d_res, base = _interleaved(model, finalists, QUICK_ROUNDS if quick else ROUNDS,
                                               0.0 if quick else MIN_SPAN)
        d_err = _max_rel_error(d_res.moduli, np.abs(ref))
        m_s, _, m_res, _ = _interleaved(model, [], 1, 0.0 if quick else MIN_SPAN, accuracy="multipliers")
        m_err = _max_rel_multiplier_error(m_res.multipliers, ref)
        log(f"  default magnus6: {d_s * 1e3:.3f} ms (N={d_res.n_steps}, moduli err={d_err:.1e}, "
            f"est={d_res.error_estimate:.1e}); accuracy='multipliers': {m_s * 1e3:.3f} ms "
            f"(N={m_res.n_steps}, multiplier err={m_err:.1e})")
        best = None
        if finalists:
            i = int(np.argmin(base))
            best = (base[i], finalists[i][1], finalists[i][2], finalists[i][3])
            log(f"  baseline finalists: " + ", ".join(f"{f[1]} {f[2]:.0e} {b * 1e3:.1f} ms"
                                                     for f, b in zip(finalists, base)))
        results.append(CaseResult(
            case=label, omega=k * math.pi, kp=kp, kd=kd,
            reference_moduli=[float(x) for x in np.abs(ref)], reference_seconds=ref_s,
            default_ms=d_s * 1e3, default_repeats=d_rep, default_n_steps=int(d_res.n_steps),
            default_max_rel_error=d_err, default_error_estimate=float(d_res.error_estimate),
            multipliers_ms=m_s * 1e3, multipliers_n_steps=int(m_res.n_steps), multipliers_max_rel_error=m_err,
            best_method=best[1] if best else None, best_rtol=best[2] if best else None,
            best_ms=best[0] * 1e3 if best else None, best_max_rel_error=best[3] if best else None,
            ratio=(best[0] / d_s) if best else None, tried=tried,
        ))
    timed = [r for r in results if r.best_ms is not None]
    total_ratio = (sum(r.best_ms for r in timed) / sum(r.default_ms for r in timed)) if timed else None
    table = _table(results, total_ratio) + f"\nsmall-system Magnus kernel: {_kernel_name()}"
    print(table)
    payload = {
        "quick": quick,
        "reference": reference,
        "target_rel_error": TARGET,
        "modulus_floor": MODULUS_FLOOR,
        "rtols": rtols,
        "methods": IVP_METHODS,
        "total_ratio": total_ratio,
        "kernel": _kernel_name(),
        "clock": CLOCK_NAME,
        "cases": [asdict(r) for r in results],
        "platform": {"python": platform.python_version(), "numpy": np.__version__,
                     "scipy": scipy.__version__, "machine": platform.machine()},
        "table": table,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "floquet_speed.json").write_text(json.dumps(payload, indent=2))
    return payload


def _kernel_name() -> str:
    """Which implementation of the small-system Magnus batch ran: the compiled (numba) kernel, or the
    numpy stacks (numba missing, or ``FLEXSTAB_NUMBA=0``: run it so to measure that path)."""
    from stability import _compiled

    return "compiled (numba)" if _compiled.available() else "numpy (no numba, or FLEXSTAB_NUMBA=0)"


def _table(results, total_ratio) -> str:
    lines = [
        f"{'case':8s} {'default ms':>10s} {'N':>5s} {'err':>8s} | {'best scipy':>14s} "
        f"{'rtol':>6s} {'ms':>10s} {'err':>8s} | {'ratio':>7s} || {'mult. ms':>8s} {'N':>5s} {'mult.err':>8s}",
        "-" * 112,
    ]
    for r in results:
        if r.best_ms is None:
            base = f"{'none passed':>14s} {'':>6s} {'':>10s} {'':>8s}"
            ratio = f"{'-':>7s}"
        else:
            base = f"{r.best_method:>14s} {r.best_rtol:6.0e} {r.best_ms:10.1f} {r.best_max_rel_error:8.1e}"
            ratio = f"{r.ratio:6.0f}x"
        lines.append(f"{r.case:8s} {r.default_ms:10.3f} {r.default_n_steps:5d} "
                     f"{r.default_max_rel_error:8.1e} | {base} | {ratio} || {r.multipliers_ms:8.3f} "
                     f"{r.multipliers_n_steps:5d} {r.multipliers_max_rel_error:8.1e}")
    lines.append("-" * 112)
    if total_ratio is not None:
        sd = sum(r.default_ms for r in results if r.best_ms is not None)
        sb = sum(r.best_ms for r in results if r.best_ms is not None)
        sm = sum(r.multipliers_ms for r in results if r.best_ms is not None)
        lines.append(f"total: baseline {sb:.1f} ms / default {sd:.3f} ms = {total_ratio:.0f}x   "
                     f"(accuracy='multipliers': {sm:.3f} ms = {sb / sm:.0f}x)")
    lines.append("ms = CPU milliseconds; err = max relative error of the moduli >= 1e-6 of the largest; "
                 "mult.err = of the complex multipliers")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 cases, 2 tolerances")
    ap.add_argument("--out", type=Path, default=Path("results"), help="output directory (default: results)")
    ap.add_argument("--reference", choices=["paper", "dop853"], default=None,
                    help="reference for the accuracy check (default: dop853 at rtol 1e-13)")
    ap.add_argument("--quiet", action="store_true", help="print only the table")
    args = ap.parse_args(argv)
    run(quick=args.quick, out=args.out, reference=args.reference, verbose=not args.quiet)
    return 0


if __name__ == "__main__":
    sys.exit(main())
