"""``flexstab tune``: Taguchi tuning of the PD gains to a target multiplier (paper Sec. 4)."""
from __future__ import annotations

import argparse
import math
import sys

from flexstab.config import load_config
from flexstab.options import dump_json, add_model_options, positive_float, resolve_omega

__all__ = ["register", "run", "tune_report", "robust_report", "build_plant"]


def register(sub) -> None:
    p = sub.add_parser(
        "tune",
        help="tune the PD gains so that max|rho| reaches a target (Taguchi)",
        description="Iterative Taguchi tuning of (kp, kd) to max|rho| = rho_d (paper Eq. 34).",
    )
    p.add_argument("--model", choices=["reduced", "exudyn"], default="reduced")
    add_model_options(p)
    p.add_argument("--target", type=positive_float, default=None, help="rho_d (default 0.3, or from --config)")
    p.add_argument("--kp-range", type=float, nargs=2, metavar=("LO", "HI"), default=None, help="default 0 60")
    p.add_argument("--kd-range", type=float, nargs=2, metavar=("LO", "HI"), default=None, help="default 0 40")
    p.add_argument("--array", default=None, help="orthogonal array, e.g. L9 (default), L16(4^5), L25")
    p.add_argument("--tolerance", type=positive_float, default=None, help="default 1e-3 * rho_d")
    p.add_argument("--max-evaluations", type=int, default=600, metavar="N")
    p.add_argument("--elements", type=int, default=None, help="ANCF elements (exudyn model)")
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: auto)")
    p.add_argument("--compare", action="store_true", help="also run the direct optimisers (Nelder-Mead, DE)")
    p.add_argument("--robust", action="store_true",
                   help="robust design: gains crossed with an outer array of noise factors (payload, Omega, E; "
                        "[robust] in --config), compared with the nominal gains over a fine noise grid")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def build_plant(model: str, cfg, omega: float, constants: str, elements=None):
    """The plant object (``with_gains(kp, kd)``) for the chosen model."""
    if model == "reduced":
        from mbs_models.reduced import ReducedModel

        return ReducedModel(omega=omega, params=cfg.manipulator, constants=constants)
    from linearize.link_floquet import exudyn_plant  # the Exudyn linearisation

    # prepared: the linearisation is interpolated, solved and balanced once, not per gain pair
    return exudyn_plant(cfg.manipulator, omega=omega, elements=elements or cfg.elements, prepared=True)


def robust_report(args: argparse.Namespace) -> dict:
    """``tune --robust``: nominal vs robust gains, judged over the ``[robust]`` noise grid."""
    from flexstab.executor import make_executor
    from flexstab.robust import ReducedNoisePlant, compare_nominal_robust
    from taguchi.robust import RobustConfig
    from taguchi.tuning import TuningConfig

    if args.model != "reduced":
        raise ValueError("--robust is available for --model reduced")
    cfg = load_config(args.config)
    rs = cfg.robust
    tcfg = TuningConfig(
        target=args.target if args.target is not None else cfg.target,
        kp_range=tuple(args.kp_range) if args.kp_range else cfg.kp_range,
        kd_range=tuple(args.kd_range) if args.kd_range else cfg.kd_range,
        array=args.array, tolerance=args.tolerance, max_evaluations=args.max_evaluations,
    )
    noise = rs.noise_factors(cfg.manipulator.tip_mass)
    # the crossed arrays need (inner + 1) x outer runs per experiment: budget per experiment x iterations
    rcfg = RobustConfig(
        tuning=TuningConfig(target=tcfg.target, kp_range=tcfg.kp_range, kd_range=tcfg.kd_range, array=args.array,
                            max_evaluations=10**6),
        noise=noise, outer_array=rs.outer_array, sn=rs.sn, max_iterations=rs.max_iterations,
    )
    rcfg.outer()  # validates the outer array early
    omega = resolve_omega(args, cfg)
    factory = ReducedNoisePlant(omega=omega, params=cfg.manipulator, constants=args.constants)
    n_tasks = tcfg.orthogonal_array().n_runs * len(rcfg.outer_runs())
    with make_executor("dask" if args.scheduler else "auto", max_workers=args.workers, scheduler=args.scheduler,
                       n_tasks=n_tasks) as ex:
        cmp = compare_nominal_robust(factory, tcfg, rcfg, grid_points=rs.grid, executor=ex)
    out = {"model": args.model, "omega": omega, "period": 2 * math.pi / omega, "robust_design": True}
    out.update(cmp.to_dict())
    out["converged"] = cmp.nominal.converged
    return out


def _print_robust(d: dict) -> None:
    nom, rob = d["nominal"], d["robust"]
    print(f"Omega = {d['omega']:.6g} rad/s, target rho_d = {d['target']:g}; robust design: inner "
          f"{rob['inner_array']} x outer {rob['outer_array']}, S/N '{rob['sn_kind']}'")
    for n in rob["noise"]:
        print(f"  noise {n['name']}: [{n['low']:g}, {n['high']:g}], nominal {n['nominal']:g}, {n['levels']} levels")
    print(f"{'':>8} {'kp':>10} {'kd':>10} {'nominal max|rho|':>17} {'worst on grid':>14}  worst at")
    for label, row in (("nominal", nom), ("robust", rob["check"])):
        g = row["gains"]
        print(f"{label:>8} {g[0]:10.5g} {g[1]:10.5g} {row['nominal']:17.6f} {row['worst']:14.6f}  {row['worst_noise']}")
    print(f"worst case over {d['grid_size']} grid points lowered by {d['worst_case_improvement']:.4g} "
          f"({d['worst_case_improvement_percent']:.2f} %); cost at nominal: |max|rho| - rho_d| "
          f"{'+' if d['nominal_cost'] >= 0 else ''}{d['nominal_cost']:.3g}")
    print(f"robust tuning: {rob['status']}, {rob['evaluations']} evaluations; total {d['elapsed']:.1f} s")


def tune_report(args: argparse.Namespace) -> dict:
    """Run the tuning described by ``args``; return the JSON-ready dict."""
    from flexstab.executor import make_executor
    from stability import floquet
    from taguchi.direct import direct_tune
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    cfg = load_config(args.config)
    omega = resolve_omega(args, cfg)
    if args.max_evaluations < 1:
        raise ValueError(f"--max-evaluations must be >= 1, got {args.max_evaluations}")
    tcfg = TuningConfig(
        target=args.target if args.target is not None else cfg.target,
        kp_range=tuple(args.kp_range) if args.kp_range else cfg.kp_range,
        kd_range=tuple(args.kd_range) if args.kd_range else cfg.kd_range,
        array=args.array,
        tolerance=args.tolerance,
        max_evaluations=args.max_evaluations,
    )
    oa = tcfg.orthogonal_array()  # validates --array early
    plant = build_plant(args.model, cfg, omega, args.constants, args.elements)
    objective = GainObjective(plant)
    # Exudyn evaluations take ~0.3 s each: worth a process pool even for one L9 array
    kind = "dask" if args.scheduler else ("process" if args.model == "exudyn" and args.workers != 1 else "auto")
    with make_executor(kind, max_workers=args.workers, scheduler=args.scheduler, n_tasks=oa.n_runs) as ex:
        res = taguchi_tune(objective, tcfg, executor=ex, progress=not args.json and sys.stderr.isatty())
    out = {"model": args.model, "omega": omega, "period": 2 * math.pi / omega}
    out.update(res.to_dict())
    if hasattr(plant, "spectral_measure"):
        # Exudyn: re-check the dominant damped multiplier with twice the propagator steps, on the
        # unprepared plant (an independent path to P(t): gains written into K, C and interpolated)
        import dataclasses

        finer = dataclasses.replace(getattr(plant, "plant", plant), n_steps=2 * plant.n_steps)
        out["verified_spectral_radius"] = finer.spectral_measure(res.kp, res.kd)
        out["verified_error_estimate"] = None
        out["elements"] = args.elements or cfg.elements
    else:
        check = floquet(plant.with_gains(res.kp, res.kd))
        out["verified_spectral_radius"] = check.spectral_radius
        out["verified_error_estimate"] = check.error_estimate
    if args.compare:
        out["direct"] = [direct_tune(objective, tcfg, m).to_dict() for m in ("nelder-mead", "differential-evolution")]
    return out


def run(args: argparse.Namespace) -> int:
    if getattr(args, "robust", False):
        d = robust_report(args)
        if args.json:
            dump_json(d, sys.stdout)
        else:
            _print_robust(d)
        return 0 if d["converged"] else 1
    d = tune_report(args)
    if not d["converged"]:
        print(f"flexstab tune: not converged: {d['message']}", file=sys.stderr)
    if args.json:
        dump_json(d, sys.stdout)
        return 0 if d["converged"] else 1
    print(f"Omega = {d['omega']:.6g} rad/s, target rho_d = {d['target']:g}, array {d['array']}")
    print(f"status: {d['status']} -- {d['message']}")
    print(f"kp = {d['kp']:.6g}   kd = {d['kd']:.6g}   max|rho| = {d['spectral_radius']:.6g}"
          f" (re-checked: {d['verified_spectral_radius']:.6g})")
    print(f"{d['evaluations']} Floquet evaluations in {len(d['iterations'])} iterations, {d['elapsed']:.2f} s")
    print("\n iter   kp range              kd range              best kp     best kd     max|rho|")
    for it in d["iterations"]:
        inc = it["incumbent"]
        print(f" {it['index']:>4}   [{it['kp_range'][0]:8.4g}, {it['kp_range'][1]:8.4g}]  "
              f"[{it['kd_range'][0]:8.4g}, {it['kd_range'][1]:8.4g}]  {inc['kp']:10.5g}  {inc['kd']:10.5g}  "
              f"{inc['spectral_radius']:.6g}")
    last = d["iterations"][-1] if d["iterations"] else None
    if last:
        rt = last["response_table"]
        print(f"\nresponse table of the last experiment (mean S/N in dB per level; levels 1..{len(rt['level_means'][0])}):")
        print(f"{'level':>7} {'kp':>12} {'kd':>12}")
        for k in range(len(rt["level_means"][0])):
            print(f"{k + 1:>7} {rt['level_means'][0][k]:12.3f} {rt['level_means'][1][k]:12.3f}")
        print(f"{'delta':>7} {rt['delta'][0]:12.3f} {rt['delta'][1]:12.3f}")
        print(f"{'rank':>7} {rt['rank'][0]:12d} {rt['rank'][1]:12d}")
        c = last["contribution_percent"]
        print(f"contribution (ANOVA on S/N): kp {c[0]:.1f} %, kd {c[1]:.1f} %, error {last['error_contribution_percent']:.1f} %")
        print(f"predicted S/N at the best levels {last['predicted_sn']:.2f} dB, "
              f"confirmation run {last['confirmation']['sn']:.2f} dB")
    for dr in d.get("direct", []):
        print(f"direct {dr['method']}: {dr['status']}, {dr['evaluations']} evaluations, "
              f"{dr['elapsed']:.2f} s, kp = {dr['kp']:.6g}, kd = {dr['kd']:.6g}")
    return 0 if d["converged"] else 1
