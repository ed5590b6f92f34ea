"""``flexstab campbell``: Floquet frequencies and damping ratios of a model against its rotation speed."""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time

from flexstab.config import load_config
from flexstab.options import dump_json, ensure_out_dir, gain_list, is_model_file, parse_omega, result_output

__all__ = ["register", "run", "campbell_report", "parse_omega_range"]

#: Default number of speeds.
DEFAULT_POINTS = 21
#: Most speeds of one diagram (each is an orbit, a linearisation and a Floquet analysis).
MAX_POINTS = 1001


def parse_omega_range(text: str) -> tuple[float, float]:
    """``"A,B"`` (rad/s or multiples of pi) -> ``(A, B)`` with ``0 < A < B``.

    Raises
    ------
    argparse.ArgumentTypeError
        Not two values, a bad value, or ``A >= B``.
    """
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 2 or not all(parts):
        raise argparse.ArgumentTypeError(f"expected two speeds A,B (rad/s or like 2pi), got {text!r}")
    try:
        lo, hi = (parse_omega(p) for p in parts)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not lo < hi:
        raise argparse.ArgumentTypeError(f"the omega range must be increasing (A < B), got {text!r}")
    return lo, hi


def register(sub) -> None:
    p = sub.add_parser(
        "campbell",
        help="Campbell diagram: Floquet frequencies and damping against the rotation speed",
        description="Floquet frequencies (principal harmonic rule) and damping ratios of a model file against "
                    "Omega, modes tracked by MAC and an optimal assignment; PNG, JSON and CSV in --out.",
    )
    p.add_argument("--model", required=True, metavar="MODEL",
                   help="a built-in model file (laval-rotor, slider-crank, single-link, two-link; exudyn is "
                        "single-link) or a model file PATH.py")
    p.add_argument("--omega-range", required=True, type=parse_omega_range, metavar="A,B",
                   help="speeds from A to B (rad/s or like 2pi), A < B")
    p.add_argument("--points", type=int, default=DEFAULT_POINTS, help=f"number of speeds (default {DEFAULT_POINTS})")
    p.add_argument("--config", metavar="FILE", help="TOML file (the single link's data)")
    p.add_argument("--elements", type=int, default=None, help="ANCF elements (built-in link models)")
    p.add_argument("--kp", type=gain_list, default=None, metavar="KP", help="PD gains per drive (default 0)")
    p.add_argument("--kd", type=gain_list, default=None, metavar="KD")
    p.add_argument("--samples", type=int, default=None, help="orbit collocation samples (even; default 32)")
    p.add_argument("--steps", type=int, default=None,
                   help="frozen-modal propagator steps per point (default: adaptive, to the engine's rtol)")
    p.add_argument("--modes", type=int, default=10, help="branches drawn, lowest median frequency first (default 10)")
    p.add_argument("--min-mac", type=float, default=None,
                   help="smallest MAC that continues a branch (default stability.campbell.MIN_MAC = 0.5)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes for the speeds (default: serial up to 32 points, else all cores)")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _check(args: argparse.Namespace) -> None:
    if isinstance(args.points, bool) or not 2 <= args.points <= MAX_POINTS:
        raise ValueError(f"--points must be an integer in 2..{MAX_POINTS}, got {args.points}")
    if args.samples is not None and (args.samples < 4 or args.samples % 2):
        raise ValueError(f"--samples must be an even integer >= 4, got {args.samples}")
    if args.steps is not None and args.steps < 4:
        raise ValueError(f"--steps must be >= 4, got {args.steps}")
    if args.modes < 1:
        raise ValueError(f"--modes must be >= 1, got {args.modes}")
    if args.min_mac is not None and not (0.0 <= args.min_mac <= 1.0):
        raise ValueError(f"--min-mac must lie in [0, 1], got {args.min_mac}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.model == "reduced":
        raise ValueError("--model reduced: the Campbell diagram needs a model file or a built-in model file "
                         "(e.g. single-link or exudyn)")


def campbell_report(args: argparse.Namespace, progress: bool = True) -> dict:
    """Compute the diagram requested by ``args``; write PNG, JSON and CSV; return the JSON-ready summary."""
    import concurrent.futures as cf

    import numpy as np

    from flexstab.campbell import (PRINCIPAL_RULE, CampbellPointTask, branch_table, campbell_tables,
                                   modes_from_points, plot_campbell)
    from flexstab.executor import SerialExecutor, make_executor
    from flexstab.progress import make_bar, progress_bars
    from flexstab.options import resolve_model_definition
    from linearize.periodic_orbit import DEFAULT_SAMPLES
    from stability.campbell import MIN_MAC, campbell

    _check(args)
    cfg = load_config(args.config)
    definition, options = resolve_model_definition(args.model, cfg, args.elements)
    lo, hi = args.omega_range
    omegas = np.linspace(lo, hi, int(args.points))
    samples = args.samples if args.samples is not None else DEFAULT_SAMPLES
    min_mac = MIN_MAC if args.min_mac is None else float(args.min_mac)
    kp = tuple(args.kp) if args.kp else ()
    kd = tuple(args.kd) if args.kd else ()
    task = CampbellPointTask(name=definition.name, source=definition.source if is_model_file(args.model) else None,
                             options=options, kp=kp, kd=kd, samples=samples, n_steps=args.steps)
    out_dir = ensure_out_dir(args.out)
    t0, c0 = time.perf_counter(), time.process_time()
    # the command line's progress rule (flexstab.progress): tqdm on a terminal, lines on a pipe
    bar = make_bar(progress_bars() if progress else False, total=omegas.size, desc="campbell", unit="speed")

    def step(i: int, point: dict) -> None:
        bar.set_postfix_str(f"Ω = {point['omega']:.6g} rad/s, {len(point['modes'])} modes, "
                            f"{point['cpu_seconds']:.2f} s CPU")
        bar.update(1)

    close = bar.close
    points: list = [None] * omegas.size
    with make_executor("auto", max_workers=args.workers, n_tasks=omegas.size) as ex:
        try:
            if isinstance(ex, SerialExecutor):
                for i, w in enumerate(omegas):
                    points[i] = task(float(w))
                    step(i, points[i])
            else:
                futures = {ex.submit(task, float(w)): i for i, w in enumerate(omegas)}
                for f in cf.as_completed(futures):
                    i = futures[f]
                    points[i] = f.result()
                    step(i, points[i])
        finally:
            close()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    result = campbell(omegas, modes_from_points(points), min_mac=min_mac)
    branches = branch_table(result)
    tag = hashlib.sha1(json.dumps([definition.name, definition.source, repr(sorted(options.items())), lo, hi,
                                   int(args.points), kp, kd, samples, args.steps, min_mac]).encode()).hexdigest()[:8]
    stem = out_dir / f"campbell_{definition.name}_{tag}"
    png = plot_campbell(result, branches, stem.with_suffix(".png"), max_branches=args.modes,
                        title=f"Campbell diagram of {definition.name} ({omegas.size} speeds, "
                              f"Ω = {lo:.4g} .. {hi:.4g} rad/s; modes tracked by MAC)")
    csv_path = stem.with_suffix(".csv")
    campbell_tables(result, points, csv_path)
    point_cpu = [p["cpu_seconds"] for p in points]
    summary = {
        "model": args.model,
        "omegas": omegas.tolist(),
        "kp": list(kp), "kd": list(kd),
        "rule": PRINCIPAL_RULE,
        "tracking": "MAC of the displacement shapes at t = 0 with each branch's last shape, one-to-one by "
                    "scipy.optimize.linear_sum_assignment on 1 - MAC; below min_mac a new branch",
        "min_mac": min_mac,
        "branches": branches,
        "points": [{k: v for k, v in p.items() if k != "modes"} | {"modes": [
            {k: v for k, v in m.items() if k != "shape"} | {"branch": int(result.tracking.branches[i][j])}
            for j, m in enumerate(p["modes"])]} for i, p in enumerate(points)],
        "timing": {"wall_seconds": wall, "cpu_seconds_this_process": cpu,
                   "cpu_seconds_per_point": point_cpu,
                   "cpu_seconds_per_point_mean": float(np.mean(point_cpu))},
        "figures": [str(png)],
        "csv": str(csv_path),
        "json": str(stem.with_suffix(".json")),
    }
    from stability.serialization import json_ready

    stem.with_suffix(".json").write_text(json.dumps(json_ready(summary)))
    return summary


def run(args: argparse.Namespace) -> int:
    s = campbell_report(args, progress=True)
    with result_output(args):
        _print(args, s)
    return 0


def _print(args: argparse.Namespace, s: dict) -> None:
    if args.json:
        dump_json(s, sys.stdout)
    else:
        print(f"Campbell diagram: {len(s['omegas'])} speeds, {len(s['branches'])} branches "
              f"({s['timing']['cpu_seconds_per_point_mean']:.2f} s CPU per speed)")
        for b in s["branches"][:args.modes]:
            f = [v for v in b["frequency_hz"] if v is not None]
            z = [v for v in b["damping_ratio"] if v is not None]
            print(f"  branch {b['branch']:>3} {b['label'] or 'mode':<14} f = {min(f):.5g} .. {max(f):.5g} Hz, "
                  f"zeta = {min(z):.3g} .. {max(z):.3g}")
        print("figures: " + ", ".join(s["figures"]) + f"; table: {s['csv']}; data: {s['json']}")
