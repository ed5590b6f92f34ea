"""``flexstab campbell``: Floquet frequencies and damping ratios of a model against its rotation speed."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from flexstab.options import dump_json, gain_list, parse_omega, result_output

__all__ = ["register", "run", "campbell_options", "parse_omega_range"]

#: Default number of speeds.
DEFAULT_POINTS = 21


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
                   help="a built-in model file (laval-rotor, slider-crank, single-link, two-link) or a model file PATH.py")
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


def campbell_options(args: argparse.Namespace) -> "CampbellOptions":
    """The :class:`~flexstab.campbell.CampbellOptions` of the parsed command line."""
    from flexstab.campbell import CampbellOptions

    return CampbellOptions(model=args.model, omega_range=tuple(args.omega_range), points=args.points,
                           kp=tuple(args.kp) if args.kp else (), kd=tuple(args.kd) if args.kd else (),
                           samples=args.samples, steps=args.steps, elements=args.elements, modes=args.modes,
                           min_mac=args.min_mac, workers=args.workers, out=Path(args.out))


def run(args: argparse.Namespace) -> int:
    from flexstab.campbell import campbell_diagram, check_campbell_options
    from flexstab.config import load_config

    opts = campbell_options(args)
    check_campbell_options(opts)  # the options alone, before the configuration and the model
    s = campbell_diagram(opts, load_config(args.config), progress=True)
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
