#!/usr/bin/env python3
"""Matrix exponentials of the single link's frozen-modal Magnus exponents: block diagonalisation vs scipy.

Why: the dense Floquet stage at 64 elements is mostly ``scipy.linalg.expm`` of
``h P_hat``, 516 x 516.  For each mesh: the periodic orbit, the Table 3 linearisation and the
frozen-modal frames (:func:`stability.modal.modal_system`, as ``benchmarks/scale.py --frame
modal`` builds them), then the magnus2 exponents ``h P_hat(t_k + h/2)`` with ``h = T / steps``
at ``--samples`` midpoints spread over the period, balanced as :func:`stability.floquet`
balances them.  Per exponent, measured in the same run (CPU seconds, single-threaded BLAS):
``scipy.linalg.expm`` (the baseline the floquet path uses today), and
:func:`stability.expm.expm_near_block_diagonal` over the frame's clusters, with its sweeps
(GEMMs), residual, ``cond(Z)``, error bound and the 1-norm distance to scipy's result; also
one ``n x n`` GEMM for the unit of work.  ``--floquet`` also times the dense Floquet stage
(``modal_floquet``, 144 extrapolated magnus2 steps) both ways and compares the multipliers.

Measured 2026-11-27 (2 shared cores, loaded; CPU ms per exponential, single-threaded BLAS)::

    el  n    ||hP||_1  GEMM  scipy  block  ratio  sweeps  max ||E_b - E_s||_1
    16  132  4.1e3     0.19    4.6    6.6  0.70   2-3     7.4e-11
    32  260  1.3e4     1.16   25.1   15.0  1.67   2-3     1.5e-11
    64  516  5.2e4     7.69  175.9   53.5  3.29   2       6.6e-11
    dense Floquet stage at 64 el (144 extrapolated magnus2 steps): 41.4 s -> 24.3 s CPU

(``stability.floquet.BLOCK_EXPM_MIN_N = 200``: below it the floquet path keeps scipy.)

Usage::

    python3 benchmarks/expm_speed.py                      # 16 32 64 elements (130/260/516 states)
    python3 benchmarks/expm_speed.py --elements 16 --floquet
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

KP, KD, OMEGA = 37.1617, 29.2410, 2.0 * math.pi


def _cpu(fn, repeat: int):
    t = time.process_time()
    for _ in range(repeat):
        out = fn()
    return (time.process_time() - t) / repeat, out


def mesh(elements: int, steps: int, samples: int, floquet: bool) -> dict:
    import numpy as np
    import scipy.linalg

    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from stability.expm import expm_near_block_diagonal
    from stability.floquet import _balancing_scale, _samples
    from stability.modal import modal_floquet, modal_system
    from stability.periodic import PeriodicMatrixFunction

    t0 = time.process_time()
    orbit = find_orbit("single-link", OMEGA, samples=32, elements=elements)
    lin = linearize_orbit(orbit, KP, KD)
    system = modal_system(lin)
    setup = time.process_time() - t0
    blocks = tuple(system.clusters)
    wrapped = PeriodicMatrixFunction(system, None)
    T = wrapped.period
    scale = _balancing_scale(_samples(wrapped, T))
    h = T / steps
    idx = np.unique(np.linspace(0, steps - 1, samples).astype(int))
    Om = h * wrapped.evaluate((idx + 0.5) * h)
    if scale is not None:
        Om = Om * (scale[None, :] / scale[:, None])
    n = Om.shape[-1]
    gemm, _ = _cpu(lambda: Om[0] @ Om[1], 5)
    rows = []
    for A in Om:
        ts, Es = _cpu(lambda: scipy.linalg.expm(A), 1)
        tb, r = _cpu(lambda: expm_near_block_diagonal(A, blocks), 1)
        diff = float(np.abs(r.matrix - Es).sum(axis=0).max()) if r.ok else math.nan
        rows.append((ts, tb, r.sweeps, r.residual, r.condition, r.error_bound, diff, r.reason))
    ts = float(np.mean([x[0] for x in rows]))
    tb = float(np.mean([x[1] for x in rows]))
    rec = {"elements": elements, "n": n, "setup_cpu": setup, "norm": float(np.abs(Om).sum(axis=1).max()),
           "clusters": {int(s): blocks.count(s) for s in set(blocks)}, "gemm_ms": 1e3 * gemm,
           "scipy_ms": 1e3 * ts, "block_ms": 1e3 * tb, "ratio": ts / tb,
           "sweeps": sorted({x[2] for x in rows}), "residual_max": max(x[3] for x in rows),
           "cond_max": max(x[4] for x in rows), "bound_max": max(x[5] for x in rows),
           "diff_max": max(x[6] for x in rows), "refused": [x[7] for x in rows if x[7]]}
    if floquet:
        for name, opts in (("scipy", {"expm_blocks": None}), ("block", {})):
            t, res = _cpu(lambda: modal_floquet(lin, basis=system, method="magnus2", n_steps=144,
                                                accuracy="moduli", extrapolate=True, **opts), 1)
            rec[f"floquet_{name}_cpu"] = t
            rec[f"floquet_{name}"] = res
        a, b = rec.pop("floquet_scipy"), rec.pop("floquet_block")
        d = np.abs(a.multipliers[:, None] - b.multipliers[None, :])
        rec["floquet_change"] = float(max(d.min(axis=1).max(), d.min(axis=0).max()))
        rec["floquet_estimate"] = float(b.error_estimate)
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, nargs="+", default=[16, 32, 64])
    ap.add_argument("--steps", type=int, default=144, help="magnus2 steps per period (h = T / steps)")
    ap.add_argument("--samples", type=int, default=6, help="exponents timed per mesh")
    ap.add_argument("--floquet", action="store_true", help="also time the dense Floquet stage both ways")
    args = ap.parse_args(argv)
    if min(args.elements) < 1 or args.steps < 1 or args.samples < 1:
        print("expm_speed: elements, steps and samples must be positive", file=sys.stderr)
        return 2
    print("| el | n | ||hP||_1 | clusters | GEMM ms | scipy expm ms | block ms | ratio | sweeps | "
          "max residual | max cond(Z) | max bound | max ||E_b - E_s||_1 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for el in args.elements:
        r = mesh(el, args.steps, args.samples, args.floquet)
        print(f"| {el} | {r['n']} | {r['norm']:.3g} | {r['clusters']} | {r['gemm_ms']:.2f} | {r['scipy_ms']:.1f} | "
              f"{r['block_ms']:.1f} | {r['ratio']:.2f} | {r['sweeps']} | {r['residual_max']:.1e} | "
              f"{r['cond_max']:.3f} | {r['bound_max']:.1e} | {r['diff_max']:.1e} |", flush=True)
        if r["refused"]:
            print(f"  refused (fell back): {r['refused']}")
        if args.floquet:
            print(f"  dense Floquet (144 steps, extrapolated): scipy {r['floquet_scipy_cpu']:.2f} s, "
                  f"block {r['floquet_block_cpu']:.2f} s CPU; multipliers moved {r['floquet_change']:.2e} "
                  f"(Richardson estimate {r['floquet_estimate']:.2e})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
