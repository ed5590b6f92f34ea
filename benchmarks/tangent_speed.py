#!/usr/bin/env python3
"""CPU seconds of the orbit's tangent blocks (``linearize.periodic_orbit.tangent_blocks``) by route.

For the single link at Omega = 2 pi (32 samples) and each ``--elements``: the periodic
orbit once, then the force and damping Jacobians at its samples by

* ``per column``: one Richardson difference per coordinate (``_force_fd``, the route
  before column colouring; ``4 n`` right-hand sides per Jacobian and sample),
* ``coloured``: ``tangent_blocks(use_exudyn_jacobian=False)`` (structurally orthogonal
  column groups of the coupling pattern, with the directional check),
* ``exudyn``: ``tangent_blocks(use_exudyn_jacobian=True)`` (Exudyn's own Jacobians,
  accepted by :func:`~linearize.periodic_orbit._exudyn_jacobians_ok`),

with the largest difference of each to the per-column ``K`` and ``C`` relative to the
largest entry (coloured: round-off only; Exudyn: the per-column differences' own error).
Each figure is the minimum over ``--repeat`` runs (CPU time: the machine is shared).

Usage::

    python3 benchmarks/tangent_speed.py --elements 8 16 32 64
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _best(fun, repeat: int):
    best, out = math.inf, None
    for _ in range(repeat):
        c0 = time.process_time()
        out = fun()
        best = min(best, time.process_time() - c0)
    return best, out


def measure(elements: int, repeat: int = 1) -> dict:
    """One mesh: the three routes on the same orbit samples."""
    import numpy as np

    from linearize import periodic_orbit as po
    from mbs_models.model_file import build_model

    orbit = po.find_orbit("single-link", 2 * math.pi, samples=32, elements=elements, verify=False)
    col = po._Collocation(build_model(orbit.model, orbit.omega), orbit.samples)
    system = col.system
    args = (system, col.times, orbit.q, orbit.q_t, orbit.q_tt, orbit.lambdas)
    const_mass = system.mass_is_constant(orbit.q[0])

    def per_column():
        return [po._force_fd(system, orbit.q[k], orbit.q_t[k], orbit.q_tt[k], float(col.times[k]),
                             po.RICHARDSON_STEP, const_mass) for k in range(orbit.samples)]

    t_col, ref = _best(per_column, repeat)
    K_ref = np.array([kc[0] for kc in ref])
    C_ref = np.array([kc[1] for kc in ref])
    t_coloured, tb_c = _best(lambda: po.tangent_blocks(*args, use_exudyn_jacobian=False), repeat)
    t_exudyn, tb_e = _best(lambda: po.tangent_blocks(*args, use_exudyn_jacobian=True), repeat)
    sk, sc = float(np.max(np.abs(K_ref))), max(float(np.max(np.abs(C_ref))), 1e-300)
    return {
        "elements": elements, "ode2": system.n, "colours": len(system.coupling_pattern().force_colours),
        "cpu_s": {"per_column": t_col, "coloured": t_coloured, "exudyn": t_exudyn},
        "note": "coloured and exudyn include M, C_q and the reaction stiffness; per_column is K_force and C only",
        "max_rel_diff_to_per_column": {
            "coloured_K": float(np.max(np.abs(tb_c.K_force - K_ref))) / sk,
            "coloured_C": float(np.max(np.abs(tb_c.C - C_ref))) / sc,
            "exudyn_K": float(np.max(np.abs(tb_e.K_force - K_ref))) / sk,
            "exudyn_C": float(np.max(np.abs(tb_e.C - C_ref))) / sc,
        },
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, nargs="+", default=[8, 16, 32])
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args(argv)
    rows = [measure(e, args.repeat) for e in args.elements]
    print(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
