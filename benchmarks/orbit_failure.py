#!/usr/bin/env python3
"""CPU seconds of a failing periodic-orbit search (``linearize.find_orbit`` raising ``OrbitConvergenceError``).

The single link with a very soft beam (``--youngs-modulus``, default 2e7 N/m^2) at 2 pi, 32 samples, for each
``--elements``: CPU seconds to the one-line failure, the Newton iterations, the omegas (as fractions of omega)
the collocation was built at (the target and each continuation solve), and the message.  The continuation
starts at omega/2 and halves a start without an orbit at most
``linearize.periodic_orbit.CONTINUATION_START_HALVINGS`` times.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _measure(elements: int, youngs_modulus: float) -> dict:
    from linearize import periodic_orbit as po
    from mbs_models.parameters import ManipulatorParameters

    omega = 2 * math.pi
    omegas: list = []
    real = po._Collocation.__init__

    def recording(self, built, samples, solver="auto"):
        omegas.append(float(built.omega) / omega)
        real(self, built, samples, solver)

    po._Collocation.__init__ = recording
    c0 = time.process_time()
    try:
        orbit = po.find_orbit("single-link", omega, elements=elements,
                              params=ManipulatorParameters(youngs_modulus=youngs_modulus))
        message, iterations = f"converged: residual {orbit.residual:.1e}", orbit.iterations
    except po.OrbitConvergenceError as exc:
        message, iterations = str(exc), len(exc.residuals)
    finally:
        po._Collocation.__init__ = real
    return {"elements": elements, "youngs_modulus": youngs_modulus, "cpu_seconds": time.process_time() - c0,
            "newton_iterations": iterations, "omega_factors": omegas, "message": message}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", default="1,8", help="ANCF elements, comma-separated")
    ap.add_argument("--youngs-modulus", type=float, default=2e7)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = [_measure(int(e), args.youngs_modulus) for e in args.elements.split(",") if e]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        print(f"{r['elements']} elements: {r['cpu_seconds']:.2f} s CPU, {r['newton_iterations']} Newton iterations, "
              f"omega factors {', '.join(f'{f:.4g}' for f in r['omega_factors'])}\n  {r['message']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
