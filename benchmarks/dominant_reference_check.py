#!/usr/bin/env python3
"""Does the ``accuracy="dominant"`` estimate of the frozen-modal dense Floquet bound its error? (independent reference)

Single link, Omega = 2 pi, Table 3 gains (the case of ``benchmarks/scale.py``).  The reference is
independent of the frozen-modal frames: the same linearisation propagated in the model's own
coordinates (:func:`stability.floquet`, ``magnus2``, fixed ``--reference`` step counts, e.g. 16384
32768; their difference in the spectral radius is printed as the reference's own uncertainty).
For each ``N`` of ``--steps``: :func:`stability.modal.modal_floquet` (``magnus2``,
``extrapolate=True``, ``accuracy="dominant"``), without and with the non-nested check solve
(``check=True``), its estimate, and its true error: of the spectral radius and of every reference
modulus within ``DOMINANT_BAND`` of the reference spectral radius (sorted moduli, relative).

Timings are CPU seconds of this process (shared machine).

Usage::

    python3 benchmarks/dominant_reference_check.py --elements 8 --steps 54 72 144 216 288
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.scale import KD, KP, OMEGA  # noqa: E402


def main(argv=None) -> int:
    import numpy as np

    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from stability import floquet
    from stability.floquet import DOMINANT_BAND
    from stability.modal import modal_floquet, modal_system

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--elements", type=int, default=8)
    ap.add_argument("--steps", type=int, nargs="+", default=[54, 72, 144, 216, 288])
    ap.add_argument("--reference", type=int, nargs="+", default=[16384, 32768])
    args = ap.parse_args(argv)
    if min(args.steps) < 8 or min(args.reference) < 8:
        ap.error("step counts must be >= 8")
    orbit = find_orbit("single-link", OMEGA, samples=32, elements=args.elements)
    lin = linearize_orbit(orbit, KP, KD)
    refs = []
    for n in sorted(args.reference):
        t = time.process_time()
        r = floquet(lin, method="magnus2", n_steps=n, accuracy="moduli", error_estimate=False)
        refs.append(np.sort(np.abs(r.multipliers))[::-1])
        print(f"reference {n} steps (model coordinates): rho - 1 = {refs[-1][0] - 1:.6e}, "
              f"{time.process_time() - t:.1f} CPU s", flush=True)
    ref = refs[-1]
    band = ref >= ref[0] * (1.0 - DOMINANT_BAND)
    unc = max(abs(m[0] - ref[0]) / ref[0] for m in refs)
    print(f"{args.elements} elements: {int(band.sum())} reference moduli in the band, references differ "
          f"by {unc:.1e} in rho\n", flush=True)
    print("| N | check | estimate | error of rho | error, band | bounded | CPU s |\n|---|---|---|---|---|---|---|")
    system = modal_system(lin)
    for N in args.steps:
        for check in (False, True):
            t = time.process_time()
            r = modal_floquet(lin, basis=system, method="magnus2", n_steps=N, accuracy="dominant",
                              extrapolate=True, check=check)
            m = np.sort(np.abs(r.multipliers))[::-1]
            err = np.abs(m[band] - ref[band]) / ref[band]
            print(f"| {N} | {'yes' if check else 'no'} | {r.error_estimate:.2e} | {err[0]:.2e} | {err.max():.2e} | "
                  f"{'yes' if err.max() <= r.error_estimate else '**no**'} | {time.process_time() - t:.2f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
