"""``flexstab chart``: stability charts over the gain plane and over Omega."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from flexstab.config import load_config
from flexstab.options import dump_json, add_model_options, omega_type, positive_float, resolve_omega

__all__ = ["register", "run", "make_charts"]


def register(sub) -> None:
    p = sub.add_parser(
        "chart",
        help="max|rho| over a (kp, kd) grid and against Omega",
        description="Stability charts (reduced model). Interrupted sweeps resume from what they wrote.",
    )
    p.add_argument("--model", choices=["reduced", "exudyn"], default="reduced",
                   help="reduced (default) or exudyn (dominant damped multiplier; slower: use --grid ~11)")
    p.add_argument("--elements", type=int, default=None, help="ANCF elements (exudyn model)")
    add_model_options(p)
    p.add_argument("--kp-range", type=float, nargs=2, metavar=("LO", "HI"), default=None)
    p.add_argument("--kd-range", type=float, nargs=2, metavar=("LO", "HI"), default=None)
    p.add_argument("--grid", type=int, default=None, help="points per gain axis (default 41; exudyn 11)")
    p.add_argument("--target", type=positive_float, default=None, help="rho_d contour and Taguchi path")
    p.add_argument("--omega-range", type=omega_type, nargs=2, metavar=("LO", "HI"), default=None,
                   help="Omega range of the second chart (default pi 10pi)")
    p.add_argument("--omega-points", type=int, default=None, help="default 181; exudyn 8")
    p.add_argument("--kp", type=float, default=None, help="fixed gains of the Omega chart (default: tuned)")
    p.add_argument("--kd", type=float, default=None)
    p.add_argument("--no-taguchi", action="store_true", help="do not draw the Taguchi path")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def make_charts(args: argparse.Namespace, progress: bool = True, cfg=None) -> dict:
    """Compute and plot both charts; return the JSON-ready summary.

    ``cfg`` (a :class:`~flexstab.config.StudyConfig`) overrides ``args.config``.
    """
    from flexstab.charts import (
        ExudynOmegaRadius, PlantRadius, ReducedRadius, check_grid, gain_chart, omega_chart, plot_gain_chart,
        plot_omega_chart,
    )
    from flexstab.executor import make_executor
    from mbs_models.reduced import ReducedModel
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    cfg = cfg if cfg is not None else load_config(args.config)
    omega = resolve_omega(args, cfg)
    kp_rng = tuple(args.kp_range) if args.kp_range else cfg.kp_range
    kd_rng = tuple(args.kd_range) if args.kd_range else cfg.kd_range
    if min(kp_rng) < 0 or min(kd_rng) < 0:
        raise ValueError("gain ranges must be >= 0")
    exudyn = getattr(args, "model", "reduced") == "exudyn"
    grid = args.grid if args.grid is not None else (11 if exudyn else 41)
    n_omega = args.omega_points if args.omega_points is not None else (8 if exudyn else 181)
    kp = check_grid(*kp_rng, grid, "kp")
    kd = check_grid(*kd_rng, grid, "kd")
    w_lo, w_hi = args.omega_range if args.omega_range else ((math.pi, 8 * math.pi) if exudyn else (math.pi, 10 * math.pi))
    omegas = check_grid(w_lo, w_hi, n_omega, "omega")
    target = args.target if args.target is not None else cfg.target
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create output folder {str(out)!r}: {exc.strerror}") from None
    # the resumable stores are keyed by everything that changes the numbers
    import hashlib

    fingerprint = hashlib.sha1(
        json.dumps([cfg.manipulator.to_dict(), args.constants], sort_keys=True).encode()
    ).hexdigest()[:8]
    if exudyn:
        from linearize.link_floquet import exudyn_plant

        elements = getattr(args, "elements", None) or cfg.elements
        tag = f"w{omega:.6g}_exudyn{elements}_{fingerprint}"
        plant = exudyn_plant(cfg.manipulator, omega=omega, elements=elements, prepared=True)
        task = PlantRadius(plant, float(omega))
        omega_task = ExudynOmegaRadius(cfg.manipulator, elements)
        objective = GainObjective(plant)
        label = f"Exudyn model ({elements} elements; hub / first bending mode)"
    else:
        tag = f"w{omega:.6g}_{args.constants}_{fingerprint}"
        task = ReducedRadius(cfg.manipulator, args.constants)
        omega_task = task
        objective = GainObjective(ReducedModel(omega, params=cfg.manipulator, constants=args.constants))
        label = "linearised reduced model"

    path = None
    tuned = None
    if not args.no_taguchi:
        tuned = taguchi_tune(objective, TuningConfig(target=target, kp_range=kp_rng, kd_range=kd_rng))
        path = [it.incumbent_gains for it in tuned.iterations]
    n_tasks = kp.size * kd.size
    kind = "dask" if args.scheduler else ("process" if exudyn and args.workers != 1 else "auto")
    with make_executor(kind, max_workers=args.workers, scheduler=args.scheduler, n_tasks=n_tasks) as ex:
        gc = gain_chart(task, omega, kp, kd, ex, out / f"chart_gains_{tag}.jsonl", target=target,
                        progress=progress)
        gkp = args.kp if args.kp is not None else (tuned.kp if tuned else 0.0)
        gkd = args.kd if args.kd is not None else (tuned.kd if tuned else 0.0)
        otag = tag.split("_", 1)[1]
        oc = omega_chart(omega_task, omegas, gkp, gkd, ex, out / f"chart_omega_{otag}_{gkp:.6g}_{gkd:.6g}.jsonl",
                         progress=progress)
    # figure and summary names identify every input that changes what is drawn (grid, ranges, target,
    # Omega range, gains), so a coarse chart never overwrites the study's chart of the same system
    drawn = hashlib.sha1(json.dumps(
        [tag, kp.tolist(), kd.tolist(), target, omegas.tolist(), gkp, gkd, bool(args.no_taguchi)]
    ).encode()).hexdigest()[:8]
    name = f"{tag}_{kp.size}x{kd.size}_{drawn}"
    png1 = plot_gain_chart(gc, out / f"chart_gains_{name}.png", path, label=label)
    png2 = plot_omega_chart(oc, out / f"chart_omega_{name}.png", label=label,
                            ylabel="dominant |ρ| (hub / first bending mode)" if exudyn else "max|ρ| (spectral radius)")
    summary = {"gain_chart": gc.to_dict(), "omega_chart": oc.to_dict(),
               "taguchi_path": [list(p) for p in path] if path else None,
               "inputs": {"manipulator": cfg.manipulator.to_dict(), "constants": args.constants,
                          "model": "exudyn" if exudyn else "reduced", "omega": omega, "grid": [kp.size, kd.size],
                          "kp_range": list(kp_rng), "kd_range": list(kd_rng), "target": target,
                          "omega_range": [float(w_lo), float(w_hi)], "omega_points": int(omegas.size)},
               "figures": [str(png1), str(png2)], "json": str(out / f"chart_{name}.json")}
    (out / f"chart_{name}.json").write_text(json.dumps(summary))
    return summary


def run(args: argparse.Namespace) -> int:
    s = make_charts(args, progress=not args.json and sys.stderr.isatty())
    if args.json:
        dump_json(s, sys.stdout)
    else:
        g = s["gain_chart"]
        print(f"gain chart: {len(g['kd'])} x {len(g['kp'])} points ({g['n_loaded']} resumed, {g['n_computed']} computed)")
        print("figures: " + ", ".join(s["figures"]))
    return 0
