"""``flexstab tune``: Taguchi tuning of the PD gains to a target multiplier (paper Sec. 4)."""
from __future__ import annotations

import argparse
import sys
from typing import Optional

from flexstab.options import (add_damping_option, add_model_options, dump_json, positive_float, result_output)

__all__ = ["register", "run", "tune_options", "tune_report", "robust_report"]


def register(sub) -> None:
    p = sub.add_parser(
        "tune",
        help="tune the PD gains so that max|rho| reaches a target (Taguchi)",
        description="Iterative Taguchi tuning of (kp, kd) to max|rho| = rho_d (paper Eq. 34).",
    )
    p.add_argument("--model", default="reduced", metavar="MODEL",
                   help="reduced (default), exudyn, a built-in model file (single-link, two-link, laval-rotor, slider-crank) or a model file "
                        "PATH.py; a model with N drives tunes 2N gains (kp1, kd1, kp2, kd2, ...)")
    add_model_options(p)
    p.add_argument("--target", type=positive_float, default=None, help="rho_d (default 0.3, or from --config)")
    p.add_argument("--kp-range", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="initial range of kp (of every drive's kp); default 0 60")
    p.add_argument("--kd-range", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="initial range of kd (of every drive's kd); default 0 40")
    p.add_argument("--range", action="append", default=None, dest="factor_range", metavar="NAME=LO,HI",
                   help="initial range of one factor, e.g. kp2=0,10 (repeatable; factor names kp, kd for one "
                        "drive, kp1, kd1, kp2, ... for several); overrides --kp-range/--kd-range for it")
    p.add_argument("--array", default=None, help="orthogonal array, e.g. L9 (default), L16(4^5), L25")
    p.add_argument("--tolerance", type=positive_float, default=None, help="default 1e-3 * rho_d")
    p.add_argument("--max-evaluations", type=int, default=600, metavar="N")
    p.add_argument("--elements", type=int, default=None, help="ANCF elements (exudyn model)")
    add_damping_option(p)
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: auto; a model file: serial, the two-link all cores)")
    p.add_argument("--compare", action="store_true", help="also run the direct optimisers (Nelder-Mead, DE)")
    p.add_argument("--robust", action="store_true",
                   help="robust design: gains crossed with an outer array of noise factors (payload, Omega, E; "
                        "[robust] in --config), compared with the nominal gains over a fine noise grid")
    p.add_argument("--grid", type=int, default=None, metavar="N",
                   help="--robust: points per noise factor of the worst-case grid (default [robust] grid)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def tune_options(args: argparse.Namespace) -> "TuneOptions":
    """The :class:`~flexstab.tuning.TuneOptions` of the parsed command line."""
    from flexstab.tuning import TuneOptions

    def pair(v):
        return tuple(v) if v is not None else None

    return TuneOptions(model=args.model, omega=args.omega, constants=args.constants, target=args.target,
                       kp_range=pair(args.kp_range), kd_range=pair(args.kd_range),
                       factor_range=tuple(args.factor_range or ()), array=args.array, tolerance=args.tolerance,
                       max_evaluations=args.max_evaluations, elements=args.elements, damping=args.damping,
                       scheduler=args.scheduler, workers=args.workers, compare=args.compare, grid=args.grid)


def tune_report(args: argparse.Namespace) -> dict:
    """``flexstab tune``: :func:`flexstab.tuning.tune_gains` of the command line (its checks first, then the
    configuration); a mode no drive moves is reported on stderr."""
    from flexstab.config import load_config
    from flexstab.tuning import check_tune_options, tune_gains

    opts = tune_options(args)
    check_tune_options(opts)
    return tune_gains(opts, load_config(args.config),
                      notify=lambda line: print(f"flexstab tune: {line}", file=sys.stderr, flush=True))


def robust_report(args: argparse.Namespace) -> dict:
    """``flexstab tune --robust``: :func:`flexstab.tuning.robust_tuning` of the command line."""
    from flexstab.config import load_config
    from flexstab.tuning import robust_tuning

    if args.model not in ("reduced", "two-link"):  # before the configuration, as every option check
        raise ValueError("--robust is available for --model reduced and --model two-link")
    return robust_tuning(tune_options(args), load_config(args.config))


def _print_robust(d: dict) -> None:
    nom, rob = d["nominal"], d["robust"]
    print(f"Omega = {d['omega']:.6g} rad/s, target rho_d = {d['target']:g}; robust design: inner "
          f"{rob['inner_array']} x outer {rob['outer_array']}, S/N '{rob['sn_kind']}'")
    for n in rob["noise"]:
        print(f"  noise {n['name']}: [{n['low']:g}, {n['high']:g}], nominal {n['nominal']:g}, {n['levels']} levels")
    names = rob.get("names") or ["kp", "kd"]
    print(f"{'':>8} " + "".join(f"{s:>10} " for s in names) + f"{'nominal max|rho|':>17} {'worst on grid':>14}  worst at")
    for label, row in (("nominal", nom), ("robust", rob["check"])):
        g = row["gains"]
        print(f"{label:>8} " + "".join(f"{v:10.5g} " for v in g)
              + f"{row['nominal']:17.6f} {row['worst']:14.6f}  {row['worst_noise']}")
    print(f"worst case over {d['grid_size']} grid points lowered by {d['worst_case_improvement']:.4g} "
          f"({d['worst_case_improvement_percent']:.2f} %); cost at nominal: |max|rho| - rho_d| "
          f"{'+' if d['nominal_cost'] >= 0 else ''}{d['nominal_cost']:.3g}")
    print(f"robust tuning: {rob['status']}, {rob['evaluations']} evaluations; total {d['elapsed']:.1f} s")
    for f in rob.get("failed_runs") or []:
        print(f"failed run (iteration {f['iteration']}, inner run {f['run']}, outer run {f['outer_run']}) at "
              + ", ".join(f"{s} = {v:.6g}" for s, v in zip(names, f["gains"]))
              + ", noise " + ", ".join(f"{k} = {v:.6g}" for k, v in f["noise"].items()) + f": {f['error']}")


def _response_name(d: dict) -> str:
    return "tuned response, dominant |rho| (drive modes, bending 1)" if d.get("response") else "tuned response, max|rho|"


def run(args: argparse.Namespace) -> int:
    if getattr(args, "robust", False):
        from flexstab.progress import progress_log

        with progress_log("flexstab.robust", "tune"), progress_log("taguchi.robust", "tune"):  # stages, on stderr
            d = robust_report(args)
        with result_output(args):
            if args.json:
                dump_json(d, sys.stdout)
            else:
                _print_robust(d)
        return 0 if d["converged"] else 1
    from flexstab.tuning import check_failure

    d = tune_report(args)
    failure = check_failure(d)
    if failure:
        print(f"flexstab tune: {failure}", file=sys.stderr)
    rc = 1 if failure else 0
    with result_output(args):
        return _print_tune(args, d, rc)


def _print_tune(args: argparse.Namespace, d: dict, rc: int) -> int:
    """Print the tuning result ``d`` (a table, or one JSON object with ``--json``); return ``rc``."""
    if args.json:
        dump_json(d, sys.stdout)
        return rc
    print(f"Omega = {d['omega']:.6g} rad/s, target rho_d = {d['target']:g}, array {d['array']}")
    print(f"status: {d['status']} -- {d['message']}")
    names = d["names"]
    if len(names) == 2:
        gains = f"kp = {d['gains'][0]:.6g}   kd = {d['gains'][1]:.6g}"
        if d.get("drives"):
            gains = f"drive {d['drives'][0]}: {gains}"
        print(f"{gains}   {_response_name(d)} = {d.get('tuned_response', d['spectral_radius']):.6g} "
              f"(re-checked: {d['verified_spectral_radius']:.6g})")
    else:
        for j, drive in enumerate(d.get("drives") or [f"{j + 1}" for j in range(len(names) // 2)]):
            print(f"drive {drive}: {names[2 * j]} = {d['gains'][2 * j]:.6g}   "
                  f"{names[2 * j + 1]} = {d['gains'][2 * j + 1]:.6g}")
        print(f"{_response_name(d)} = {d.get('tuned_response', d['spectral_radius']):.6g} "
              f"(re-checked: {d['verified_spectral_radius']:.6g})")
    if d.get("spectral_radius") is not None and d.get("verdict_detail"):
        freq = d.get("spectral_radius_frequency_hz")
        err = d.get("spectral_radius_error_estimate")
        mode = d.get("spectral_radius_mode")
        print(f"whole loop: spectral radius {d['spectral_radius']:.6g}"
              + (f" ({mode}" + (f", {freq:.4g} Hz" if freq else "") + ")" if mode else "")
              + (f", relative error estimate {err:.1e}" if err is not None else ""))
        for m in d.get("spectral_radius_mesh") or []:
            print(f"  at {m['elements']} elements: {m['spectral_radius']:.6g} ({m['mode']}) -> {m['verdict']}")
        print(f"verdict: {d['verdict_detail']['message']}")
        if d.get("response_note"):
            print(f"note: {d['response_note']}")
    print(f"{d['evaluations']} Floquet evaluations in {len(d['iterations'])} iterations, {d['elapsed']:.2f} s")
    for f in d.get("failed_runs") or []:
        print(f"failed run (iteration {f['iteration']}, run {f['run']}) at "
              + ", ".join(f"{s} = {v:.6g}" for s, v in zip(names, f["gains"])) + f": {f['error']}")
    if d.get("fallback_runs"):
        print(f"{len(d['fallback_runs'])} runs used the frozen-modal product instead of Hill's value (refined to "
              f"tolerance / 4; see fallback_runs)")
    pc = d.get("propagator_choice")
    if pc and not pc["converged"]:
        print(f"warning: {pc['n_steps']} propagator steps (the cap) did not meet tolerance / 4 at the range centre "
              f"(estimate {pc['error_estimate']:.2e})")
    if d.get("harmonics_converged") is False:
        print(f"warning: Hill's harmonics ({d['harmonics']}) did not meet tolerance / 20 at the range centre "
              f"(estimate {d['harmonics_error_estimate']:.2e})")
    if len(names) == 2:
        print("\n iter   kp range              kd range              best kp     best kd     max|rho|")
        for it in d["iterations"]:
            inc = it["incumbent"]
            r0, r1 = it[f"{names[0]}_range"], it[f"{names[1]}_range"]
            print(f" {it['index']:>4}   [{r0[0]:8.4g}, {r0[1]:8.4g}]  [{r1[0]:8.4g}, {r1[1]:8.4g}]  "
                  f"{inc[names[0]]:10.5g}  {inc[names[1]]:10.5g}  {inc['spectral_radius']:.6g}")
    else:
        print("\n iter  " + "".join(f"{s + ' range':>22}" for s in names) + "   max|rho| (best: "
              + ", ".join(names) + ")")
        for it in d["iterations"]:
            inc = it["incumbent"]
            rng = "".join(f"  [{it[s + '_range'][0]:8.4g}, {it[s + '_range'][1]:8.4g}]" for s in names)
            print(f" {it['index']:>4}  {rng}   {inc['spectral_radius']:.6g} ("
                  + ", ".join(f"{inc[s]:.5g}" for s in names) + ")")
    last = d["iterations"][-1] if d["iterations"] else None
    if last:
        rt = last["response_table"]
        print(f"\nresponse table of the last experiment (mean S/N in dB per level; levels 1..{len(rt['level_means'][0])}):")
        print(f"{'level':>7}" + "".join(f"{s:>12}" for s in names))
        for k in range(len(rt["level_means"][0])):
            print(f"{k + 1:>7}" + "".join(f"{m[k]:12.3f}" for m in rt["level_means"]))
        print(f"{'delta':>7}" + "".join(f"{v:12.3f}" for v in rt["delta"]))
        print(f"{'rank':>7}" + "".join(f"{v:12d}" for v in rt["rank"]))
        c = last["contribution_percent"]
        print("contribution (ANOVA on S/N): " + ", ".join(f"{s} {v:.1f} %" for s, v in zip(names, c))
              + f", error {last['error_contribution_percent']:.1f} %")
        print(f"predicted S/N at the best levels {last['predicted_sn']:.2f} dB, "
              f"confirmation run {last['confirmation']['sn']:.2f} dB")
    for dr in d.get("direct", []):
        gains = ", ".join(f"{s} = {g:.6g}" for s, g in zip(dr["names"], dr["gains"]))
        print(f"direct {dr['method']}: {dr['status']}, {dr['evaluations']} evaluations, {dr['elapsed']:.2f} s, {gains}")
    return rc


