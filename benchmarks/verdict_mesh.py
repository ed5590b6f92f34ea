"""The verdict of the single link with the paper's Table 3 gains at several meshes (a check a person runs).

For each element count: the spectral radius of the whole closed loop (model-file route, adaptive
or fixed-step frozen-modal propagation), its own error estimate, its mode, the verdict of
:mod:`stability.verdict` and the practically undamped multipliers counted; with ``--damping BETA`` also
the damped link.  The verdict must be the same at every mesh whose multipliers are converged
(``critical`` without damping: the mesh modes stay on the unit circle).  64 elements takes about a
minute of CPU.

    python benchmarks/verdict_mesh.py --elements 8 16 64 --omega 2 [--damping 1e-5]
"""
from __future__ import annotations

import argparse
import math
import time
import warnings

from linearize.analysis import analyze
from mbs_models.paper_data import TABLE3_GAINS
from mbs_models.parameters import ManipulatorParameters


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, nargs="+", default=[8, 16, 64])
    ap.add_argument("--omega", type=int, default=2, choices=sorted(TABLE3_GAINS), help="Omega / pi of Table 3")
    ap.add_argument("--damping", type=float, default=0.0, help="Kelvin-Voigt loss time beta (s); 0 = undamped")
    ap.add_argument("--steps", type=int, default=128,
                    help="extrapolated frozen-modal steps (default 128, analyze's); 0: adaptive with the check")
    a = ap.parse_args()
    kp, kd = TABLE3_GAINS[a.omega]
    print(f"single link, Omega = {a.omega} pi, Table 3 gains kp = {kp}, kd = {kd}, beta = {a.damping:g} s "
          "(machine may be loaded: CPU seconds)")
    print(f"{'elements':>8}  {'spectral radius':>18}  {'own error':>9}  {'mode':>10}  {'verdict':>22}  "
          f"{'undamped':>9}  {'CPU s':>6}")
    opts = {"material_damping": a.damping} if a.damping else {}
    for e in a.elements:
        t = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            r = analyze("single-link", a.omega * math.pi, kp=kp, kd=kd, elements=e, params=ManipulatorParameters(),
                        n_steps=a.steps or None, **opts)
        v = r.verdict
        print(f"{e:>8}  {v.spectral_radius:>18.12f}  {v.spectral_radius_error:>9.1e}  "
              f"{v.spectral_radius_label:>10}  {v.verdict:>22}  {len(v.undamped):>4}/{v.n_multipliers:<4}  "
              f"{time.process_time() - t:>6.1f}")


if __name__ == "__main__":
    main()
