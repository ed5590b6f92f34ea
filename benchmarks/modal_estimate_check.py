#!/usr/bin/env python3
"""Does the extrapolated error estimate of the frozen-modal dense Floquet bound its true error?

Single link, Omega = 2 pi, Table 3 gains (the case of ``benchmarks/scale.py``), one linearisation
and one nested frozen-modal basis (:func:`stability.modal.modal_system`) per mesh.  For each step
count ``N`` of ``--steps``: :func:`stability.modal.modal_floquet` (``magnus2``, ``accuracy="moduli"``,
``extrapolate=True``, as ``analyze()`` and ``scale.py`` run it; ratio 3 when 9 divides ``N``) and
its true error against references: the same frames and linearisation with each of ``--reference``
steps (the error is the largest distance to any of them; their largest mutual difference is printed
as the references' own uncertainty: use step counts from different families, e.g. 1000 1100 1296
2592, because a nested family shares errors).  The error is per multiplier, over the moduli >= 1e-6 of the largest, as the
estimate's ``accuracy="moduli"`` measures it: the relative change of the sorted moduli.

``--accuracy dominant``: the estimate of :func:`stability.floquet.dominant_mask` (the spectral
radius and the multipliers that could be it) against the true error of the spectral radius and of
every reference modulus within ``DOMINANT_BAND`` of the reference spectral radius (the covered set's
part that does not depend on the estimates); the "moduli" error is printed beside it.

Timings are CPU seconds of this process (shared machine).  Writes ``results/modal_estimate_check.json``.

Usage::

    python3 benchmarks/modal_estimate_check.py --elements 8 --steps 72 135 144 153 216 576
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.scale import KD, KP, OMEGA  # noqa: E402

FLOOR = 1e-6  # stability.floquet.ESTIMATE_FLOOR: the moduli the estimate covers


def sorted_moduli(values):
    import numpy as np

    return np.sort(np.abs(np.asarray(values)))[::-1]


def run(elements: int, steps: list[int], reference: list[int], accuracy: str = "moduli",
        check: bool = False) -> dict:
    import numpy as np

    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from stability.floquet import DOMINANT_BAND
    from stability.modal import modal_floquet, modal_system

    orbit = find_orbit("single-link", OMEGA, samples=32, elements=elements)
    lin = linearize_orbit(orbit, KP, KD)
    system = modal_system(lin)

    def solve(N: int, check: bool = False):
        t = time.process_time()
        res = modal_floquet(lin, basis=system, method="magnus2", n_steps=N, accuracy=accuracy, extrapolate=True,
                            check=check)
        return res, time.process_time() - t

    refs = [solve(N) for N in sorted(reference)]
    ref = sorted_moduli(refs[-1][0].multipliers)
    keep = ref >= FLOOR * ref[0]
    # the spread of all references (any two may differ; reported, and the error below is the
    # largest distance to any of them, so that a reference's own error cannot hide a miss)
    all_refs = [sorted_moduli(r[0].multipliers) for r in refs]
    ref_unc = max(float(np.max(np.abs(m[keep] - ref[keep]) / ref[keep])) for m in all_refs)
    band = ref >= ref[0] * (1.0 - DOMINANT_BAND)  # the reference moduli within the band of its rho
    rows = []
    for N in steps:
        res, cpu = solve(N, check)
        got = sorted_moduli(res.multipliers)[keep]
        err_all = np.max([np.abs(got - m[keep]) / m[keep] for m in all_refs], axis=0)
        # "dominant": the spectral radius and the band's moduli; "moduli": every modulus >= FLOOR
        err = err_all[band[keep]] if accuracy == "dominant" else err_all
        i = int(np.argmax(err))
        mods = ref[keep][band[keep]] if accuracy == "dominant" else ref[keep]
        rows.append({"n_steps": N, "ratio": 3 if N % 9 == 0 else 2, "estimate": float(res.error_estimate),
                     "error": float(err[i]), "modulus_at_max_error": float(mods[i]),
                     "spectral_radius_error": float(err_all[0]), "moduli_error": float(err_all.max()),
                     "bounded": bool(err[i] <= res.error_estimate), "cpu_s": cpu,
                     "spectral_radius": float(res.spectral_radius)})
    return {"elements": elements, "accuracy": accuracy, "check": check, "band_size": int(band.sum()), "states": 2 * int(lin.size), "reference_steps": sorted(reference),
            "reference_uncertainty": ref_unc, "reference_estimate": float(refs[-1][0].error_estimate),
            "reference_spectral_radius": float(refs[-1][0].spectral_radius), "rows": rows}


def markdown(rec: dict) -> str:
    lines = [f"{rec['elements']} elements ({rec['states']} states): reference {rec['reference_steps'][-1]} steps, "
             f"the largest difference of the references {rec['reference_steps']} {rec['reference_uncertainty']:.1e} "
             f"(its own estimate {rec['reference_estimate']:.1e}); accuracy {rec['accuracy']}{', non-nested check' if rec.get('check') else ''}"
             + (f" ({rec['band_size']} reference moduli in the band)" if rec["accuracy"] == "dominant" else ""), "",
             "| N | ratio | estimate | true error | at modulus | bounded | error of rho | error, all moduli | CPU s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rec["rows"]:
        lines.append(f"| {r['n_steps']} | {r['ratio']} | {r['estimate']:.2e} | {r['error']:.2e} | "
                     f"{r['modulus_at_max_error']:.6f} | {'yes' if r['bounded'] else '**no**'} | "
                     f"{r['spectral_radius_error']:.1e} | {r['moduli_error']:.1e} | {r['cpu_s']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--elements", type=int, nargs="+", default=[8])
    ap.add_argument("--steps", type=int, nargs="+", default=[72, 128, 135, 144, 153, 216, 256, 360, 576])
    ap.add_argument("--reference", type=int, nargs="+", default=[1296, 2592],
                    help="reference step counts (the finest is the reference; the error is the largest "
                         "distance to any of them)")
    ap.add_argument("--check", action="store_true", help="modal_floquet(check=True): the non-nested check solve")
    ap.add_argument("--accuracy", choices=("moduli", "dominant"), default="moduli")
    ap.add_argument("--out", default=str(ROOT / "results" / "modal_estimate_check.json"))
    args = ap.parse_args(argv)
    if min(args.steps + args.reference) < 8:
        ap.error("step counts must be >= 8")
    records = []
    for e in args.elements:
        rec = run(e, args.steps, args.reference, args.accuracy, args.check)
        records.append(rec)
        print(markdown(rec), flush=True)
        print(flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(records, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
