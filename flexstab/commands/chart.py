"""``flexstab chart``: stability charts over the gain plane and over Omega."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from flexstab.options import add_model_options, dump_json, gain_list, omega_type, positive_float, result_output

__all__ = ["register", "run", "chart_options"]


def register(sub) -> None:
    p = sub.add_parser(
        "chart",
        help="max|rho| over a (kp, kd) grid and against Omega",
        description="Stability charts. Interrupted sweeps resume from what they wrote.",
    )
    p.add_argument("--model", default="reduced", metavar="MODEL",
                   help="reduced (default), exudyn (dominant damped multiplier; slower: use --grid ~11), a built-in "
                        "model file (single-link, two-link, laval-rotor, slider-crank) or a model file PATH.py (dominant labelled multiplier; "
                        "gain chart over one drive's (kp, kd), Omega chart with the orbit continued in Omega)")
    p.add_argument("--elements", type=int, default=None, help="ANCF elements (exudyn and built-in models)")
    p.add_argument("--drive", default=None, metavar="NAME",
                   help="model files: the drive whose (kp, kd) the gain chart varies (default: the first), or 'all' "
                        "(the same gains on every drive); the others stay at --kp/--kd")
    p.add_argument("--samples", type=int, default=None,
                   help="model files: collocation samples per period (even; default 32)")
    p.add_argument("--steps", type=int, default=None,
                   help="model files: magnus2 sub-intervals per Floquet evaluation (default: chosen as tune and "
                        "study --model choose them, at the centre of the gain ranges; not for the built-in two-link, "
                        "whose response is measured by Hill's method)")
    add_model_options(p)
    p.add_argument("--kp-range", type=float, nargs=2, metavar=("LO", "HI"), default=None)
    p.add_argument("--kd-range", type=float, nargs=2, metavar=("LO", "HI"), default=None)
    p.add_argument("--grid", type=int, default=None, help="points per gain axis (default 41; exudyn 11)")
    p.add_argument("--target", type=positive_float, default=None, help="rho_d contour and Taguchi path")
    p.add_argument("--omega-range", type=omega_type, nargs=2, metavar=("LO", "HI"), default=None,
                   help="Omega range of the second chart (default pi 10pi; model files 0.5 and 1.5 x Omega)")
    p.add_argument("--omega-points", type=int, default=None, help="default 181; exudyn 8; model files 9")
    p.add_argument("--kp", type=gain_list, default=None, metavar="KP",
                   help="fixed gains of the Omega chart (default: tuned); model files: one value or one per "
                        "drive a,b,...: the gains of the drives the gain chart does not vary (default 0)")
    p.add_argument("--kd", type=gain_list, default=None, metavar="KD")
    p.add_argument("--no-taguchi", action="store_true", help="do not draw the Taguchi path")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: auto; a model file: serial, and the Omega chart always "
                        "runs in this process)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def chart_options(args: argparse.Namespace) -> "ChartOptions":
    """The :class:`~flexstab.chart_runs.ChartOptions` of the parsed command line."""
    from flexstab.chart_runs import ChartOptions

    def pair(v):
        return tuple(v) if v is not None else None

    return ChartOptions(
        model=args.model, out=Path(args.out), omega=args.omega, kp_range=pair(args.kp_range),
        kd_range=pair(args.kd_range), grid=args.grid, target=args.target, omega_range=pair(args.omega_range),
        omega_points=args.omega_points,
        kp=args.kp, kd=args.kd, no_taguchi=args.no_taguchi, constants=args.constants, elements=args.elements,
        drive=args.drive, samples=args.samples, steps=args.steps, scheduler=args.scheduler, workers=args.workers)


def run(args: argparse.Namespace) -> int:
    from flexstab.chart_runs import check_chart_options, make_charts
    from flexstab.config import load_config
    from flexstab.progress import progress_bars

    opts = chart_options(args)
    check_chart_options(opts)  # the options alone, before the configuration and any numerical import
    s = make_charts(opts, load_config(args.config), progress=progress_bars())  # progress on stderr
    with result_output(args):
        if args.json:
            dump_json(s, sys.stdout)
        else:
            g = s["gain_chart"]
            if g is not None:
                print(f"gain chart: {len(g['kd'])} x {len(g['kp'])} points ({g['n_loaded']} resumed, "
                      f"{g['n_computed']} computed)")
            if s.get("note"):
                print(s["note"])
            print("figures: " + ", ".join(s["figures"]))
    return 0
