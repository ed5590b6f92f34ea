"""The full one-period map of a model file's closed loop against its prediction, with and without a mode.

Measures the map once (:func:`validation.full_map.measure_model_full_map`) and compares it with the
linearisation's whole spectrum and with the same spectrum minus the modes named by ``--omit``: the
first must agree, the second must be rejected if the omitted mode is slow.  Writes
``full_map.json`` and ``full_map_maps.npz`` (the fitted map per step level) to ``--out``.

Example (the two-link arm at its four-gain optimum, 2 elements per link)::

    python3 scripts/full_map_check.py --model two-link --elements 2 --kp 15,7.138671875 \\
        --kd 8.935546875,1.4443359375 --step 1.220703125e-4 --refinements 3 --omit "axial 9" \\
        --reuse --workers 2 --out results/full_map
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="two-link")
    ap.add_argument("--elements", type=int, default=None)
    ap.add_argument("--omega", type=float, default=2 * math.pi)
    ap.add_argument("--kp", default="0")
    ap.add_argument("--kd", default="0")
    ap.add_argument("--step", type=float, default=None, help="coarsest step (s); default: the step rule")
    ap.add_argument("--refinements", type=int, default=2)
    ap.add_argument("--omit", action="append", default=[], help="mode label removed from the second prediction")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="results/full_map")
    ap.add_argument("--reuse", action="store_true",
                    help="load a level already stored in --out (same step) instead of measuring it again")
    ap.add_argument("--amplitude-level", type=int, default=0,
                    help="level repeated at half the amplitude for the amplitude error (default 0, the cheapest; "
                         "-1 the finest)")
    ap.add_argument("--no-amplitude-check", dest="amplitude_level", action="store_const", const=None)
    args = ap.parse_args(argv)

    import numpy as np

    from flexstab.executor import make_executor
    from linearize.analysis import analyze
    from mbs_models.console import exudyn_console
    from validation.full_map import FullMapConfig, full_map_from_maps, full_map_report, measure_model_full_map
    from validation.multipliers import MODEL_AMPLITUDE, MODEL_SAMPLES

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    kp = [float(x) for x in args.kp.split(",")]
    kd = [float(x) for x in args.kd.split(",")]
    options = {} if args.elements is None else {"elements": args.elements}
    cfg = FullMapConfig(step=args.step, refinements=args.refinements)
    cpu, wall = time.process_time(), time.perf_counter()
    # level by level, each fitted map stored as soon as it is done (the perturbations are the same at every
    # level: fixed seed), so that an interrupted run leaves its finished levels
    maps, steps, resid, runner, amplitude = [], [], [], None, None

    def stored(name: str, h: "float | None"):
        f = out / name
        if not (args.reuse and f.exists()):
            return None
        z = np.load(f)
        if h is not None and not math.isclose(float(z["step"]), h, rel_tol=1e-12):
            return None
        return z

    def level_map(name: str, h: "float | None", amp: "float | None" = None):
        """The stored level ``name`` (with ``--reuse``), else one measured at step ``h`` and stored."""
        nonlocal runner
        z = stored(name, h)
        if z is not None:
            return z, "reused"
        level, runner = measure_model_full_map(
            args.model, args.omega, kp, kd,
            config=FullMapConfig(step=h, refinements=0, seed=cfg.seed, amplitude=amp, amplitude_check=False),
            executor=None if args.workers == 1 else ex, chunks=args.workers, **options)
        if level.diverged:
            raise SystemExit(f"full_map_check: error: {level.reason}")
        z = {"map": level.maps[0], "step": level.steps[0], "residual": level.fit_residual[0],
             "amplitude": level.config.amplitude}
        np.savez(out / name, **z)
        return z, f"done, {time.perf_counter() - wall:.0f} s wall"

    with make_executor("process" if args.workers > 1 else "serial", max_workers=args.workers) as ex:
        for j in range(args.refinements + 1):
            h = None if (args.step is None and not steps) else (args.step or steps[0]) / 2**j
            z, how = level_map(f"level_{j}.npz", h)
            maps.append(np.asarray(z["map"])), steps.append(float(z["step"])), resid.append(float(z["residual"]))
            amplitude = float(z["amplitude"]) if "amplitude" in z else MODEL_AMPLITUDE
            print(f"level {j} (h = {steps[-1]:g} s) {how}", flush=True)
        half = None
        if args.amplitude_level is not None:
            k = args.amplitude_level % len(steps)
            z, how = level_map(f"half_level_{k}.npz", steps[k], 0.5 * amplitude)
            half = np.asarray(z["map"])
            print(f"half amplitude at level {k} {how}", flush=True)
    n_state = maps[0].shape[0]
    result = full_map_from_maps(maps, steps, replace(cfg, step=steps[0], amplitude=amplitude),
                                n_state, n_state, resid, half_amplitude_map=half,
                                half_amplitude_level=-1 if half is None else k)
    if runner is None:
        with exudyn_console(True):
            from linearize.periodic_orbit import find_orbit
            from mbs_models.model_file import resolve_model

            definition = resolve_model(args.model, **options)
            orbit = find_orbit(definition, args.omega, samples=MODEL_SAMPLES)
    else:
        definition, orbit = runner.definition, runner.orbit
    with exudyn_console(True):
        analysis = analyze(definition, args.omega, kp=kp, kd=kd, orbit=orbit)
    full = full_map_report(result, analysis)
    omitted = full_map_report(result, analysis, omit=args.omit) if args.omit else None
    data = {"model": args.model, "options": options, "omega": args.omega, "kp": kp, "kd": kd,
            "full_prediction": full, "prediction_without": omitted,
            "parent_cpu_seconds": time.process_time() - cpu, "wall_seconds": time.perf_counter() - wall}
    (out / "full_map.json").write_text(json.dumps(data, indent=2))
    np.savez(out / "full_map_maps.npz", steps=np.array(result.steps), maps=np.array(result.maps))
    for name, rep in (("whole spectrum", full), (f"without {args.omit}", omitted)):
        if rep is None:
            continue
        print(f"prediction ({name}): {'agrees' if rep['agrees'] else 'REJECTED'}")
        for row in rep["partners"]:
            bar = "unresolved" if row["error_bar"] is None else f"+- {row['error_bar']:.2g}"
            print(f"  measured {row['modulus']:.6f} {bar} (levels "
                  f"{', '.join(f'{abs(complex(*z)):.6f}' for z in rep['levels'][rep['partners'].index(row)])}; "
                  f"resolved {row['resolved']}) -> predicted {row['predicted']} ({row['mode']})")
    ok = full["agrees"] and (omitted is None or not omitted["agrees"])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
