"""``flexstab floquet``: Floquet multipliers of the manipulator about its fundamental motion."""
from __future__ import annotations

import argparse
import math
import sys

from flexstab.options import (add_damping_option, add_model_options, dump_json, gain_list, gains_as_lists,
                              non_negative_float, result_output)

__all__ = ["register", "run", "floquet_options", "floquet_report"]


def register(sub) -> None:
    p = sub.add_parser(
        "floquet",
        help="Floquet multipliers about the fundamental motion",
        description="Floquet multipliers and stability verdict of the linearised manipulator.",
    )
    p.add_argument("--model", default="reduced", metavar="MODEL",
                   help="reduced (default; paper Eqs. 20-25), exudyn (the paper's Exudyn ANCF link: single-link with "
                        "the configured manipulator), a built-in "
                        "model file (single-link, two-link, laval-rotor, slider-crank) or a model file PATH.py (docs/model-files.md)")
    add_model_options(p)
    p.add_argument("--kp", type=gain_list, default=(0.0,), metavar="KP",
                   help="proportional gain(s): one value, or one per drive a,b,... (N m/rad)")
    p.add_argument("--kd", type=gain_list, default=(0.0,), metavar="KD",
                   help="derivative gain(s): one value, or one per drive c,d,... (N m s/rad)")
    p.add_argument("--samples", type=int, default=None,
                   help="collocation samples per period of a model file's orbit (even; default 32)")
    p.add_argument("--method", default=None,
                   help="Floquet method (magnus6, magnus4, magnus2, paper); default magnus6 for the "
                        "reduced model, magnus2 for the Exudyn model")
    p.add_argument("--elements", type=int, default=None, help="ANCF elements (exudyn model)")
    add_damping_option(p)
    p.add_argument("--bending-damping", type=non_negative_float, default=0.0,
                   help="added to --damping: Exudyn's bendingDamping of the ANCF elements (N m^2 s; default 0)")
    p.add_argument("--axial-damping", type=non_negative_float, default=0.0,
                   help="added to --damping: Exudyn's axialDamping of the ANCF elements (N s; default 0)")
    p.add_argument("--small-multipliers", choices=["flag", "qr"], default="flag",
                   help="multipliers below the rounding floor of the product: flag them (default) or "
                        "compute their moduli accurately by QR sweeps (log_moduli)")
    p.add_argument("--rtol", type=_rtol_type, default=None, metavar="R",
                   help="accuracy contract: every multiplier with modulus >= 1e-6 of the largest is certified "
                        "to this relative error, refined until it is, or reported as not certified with the "
                        "reason (default: [study] rtol of --config, else 1e-6; see docs/accuracy.md)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _rtol_type(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--rtol must be a number, got {text!r}") from None
    if not (math.isfinite(value) and 0.0 < value < 1.0):
        raise argparse.ArgumentTypeError(f"--rtol must be in (0, 1), got {text!r}")
    return value


def floquet_options(args: argparse.Namespace) -> "FloquetOptions":
    """The :class:`~flexstab.floquet_runs.FloquetOptions` of the parsed command line."""
    from flexstab.floquet_runs import FloquetOptions

    return FloquetOptions(model=args.model, omega=args.omega, kp=tuple(args.kp), kd=tuple(args.kd),
                          constants=args.constants, samples=args.samples, method=args.method,
                          elements=args.elements, damping=args.damping, bending_damping=args.bending_damping,
                          axial_damping=args.axial_damping, small_multipliers=args.small_multipliers,
                          rtol=args.rtol)


def floquet_report(args: argparse.Namespace) -> dict:
    """``flexstab floquet``: :func:`flexstab.floquet_runs.floquet_analysis` of the command line (its checks
    first, then the configuration)."""
    from flexstab.config import load_config
    from flexstab.floquet_runs import check_floquet_options, floquet_analysis

    opts = floquet_options(args)
    check_floquet_options(opts)
    return floquet_analysis(opts, load_config(args.config))


def _gains(v) -> str:
    return ", ".join(f"{x:.6g}" for x in v) if isinstance(v, (list, tuple)) else f"{v:.6g}"


def _table(d: dict) -> str:
    modes = d.get("modes")
    lines = [
        f"model: {d['model']}    omega = {d['omega']:.6g} rad/s ({d['omega'] / math.pi:.6g} pi)    T = {d['period']:.6g} s",
        f"kp = {_gains(d['kp'])}    kd = {_gains(d['kd'])}    method = {d['method']} ({d['n_steps']} steps)",
        "",
        f"{'#':>3}  {'Re rho':>14}  {'Im rho':>14}  {'|rho|':>14}  digits" + ("  mode" if modes else ""),
    ]
    for i, ((re, im), mod, dig, lg) in enumerate(
        zip(d["multipliers"], d["moduli"], d["reliable_digits"], d["log_moduli"]), 1
    ):
        label = ""
        if lg is None:  # ln 0 (JSON null): the multiplier is exactly zero as computed
            label = "  |rho| = 0 (below the smallest double)"
        elif mod == 0.0:  # underflows as a number: show it through its logarithm
            label = f"  |rho| = 10^{lg / math.log(10):.2f}"
        if modes:
            m = modes[i - 1]
            if i - 1 in (d.get("structural_indices") or ()):
                label += f"  {m.get('mode', '')} (structural: the orbit's free phase, not judged)"
            else:
                label += f"  {m.get('mode', '')}" + (" (undamped)" if m.get("undamped") else "")
        if re is None or im is None:  # phase unknown (below the rounding floor): the modulus only
            re_s, im_s = f"{'?':>14}", f"{'?':>14}"
            label += "  phase unknown"
        else:
            re_s, im_s = f"{re:>14.8g}", f"{im:>14.8g}"
        certified = d.get("certified")
        if certified and not certified[i - 1] and lg is not None and mod != 0.0 and re is not None:
            label += "  (not certified)"
        lines.append(f"{i:>3}  {re_s}  {im_s}  {mod:>14.8g}  {dig:>5.1f}{label}")
    est = d["error_estimate"]
    phase_est = d.get("phase_error_estimate")
    phase = "n/a" if phase_est is None else f"{phase_est:.1e}"
    liou = d["liouville_residual"]
    if d["liouville_source"] == "unavailable":
        liouville = "n/a (multipliers below the rounding floor; this method keeps no propagators)"
    else:
        liouville = f"{'inf' if liou is None else f'{liou:.1e}'} (from the {d['liouville_source']})"
    lines += [
        "",
        f"spectral radius  {d['spectral_radius']:.10g}   -> {d['verdict']} (tolerance {d['stability_tolerance']:.1e})"
        + (f"; judged without the structural multiplier: {d['verdict_detail']['spectral_radius']:.10g}"
           if d.get("structural_indices") and d.get("verdict_detail") else ""),
        *([f"verdict          {d['verdict_detail']['message']}"] if d.get("verdict_detail") else []),
        f"error estimate   {'n/a' if est is None else f'{est:.1e}'} (relative, of the {d.get('accuracy', 'moduli')};"
        f" phases {phase} rad)",
        f"Liouville        |det Phi / exp(int tr P) - 1| = {liouville}",
    ]
    if d.get("certified") is not None and d.get("rtol") is not None:
        reasons = [(i, r) for i, r in enumerate(d.get("uncertified_reasons") or [], 1)
                   if r and "outside the accuracy contract" not in r]
        lines.append(f"accuracy         rtol {d['rtol']:.0e}: "
                     + ("every multiplier >= 1e-6 of the largest certified" if not reasons else
                        "NOT certified: " + "; ".join(f"#{i} {r}" for i, r in reasons)))
    if "drives" in d:
        lines += [
            f"drives: {', '.join(d['drives']) or '(none)'}; dominant multiplier |rho| = {d['dominant_modulus']:.8g}",
            f"orbit residual {d['orbit_residual']:.1e} (shooting check {d['shooting_residual']:.1e}), "
            f"{d['samples']} samples, {d['ode2']} Exudyn coordinates -> {d['independent_coordinates']} independent",
        ]
        if d.get("turns"):
            lines.append("periodic up to whole turns per period: "
                         + ", ".join(f"{k} {v:+d}" for k, v in d["turns"].items()))
        if d.get("sign_flips"):
            lines.append("Euler parameters back with the opposite sign after a period: " + ", ".join(d["sign_flips"]))
        if d.get("structural_multipliers"):
            lines.append("autonomous model: the orbit's phase is free (fixed by a phase condition); one multiplier 1 "
                         "is structural, not a verdict on the motion")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    d = gains_as_lists(floquet_report(args))
    with result_output(args):
        if args.json:
            dump_json(d, sys.stdout)
        else:
            print(_table(d))
    return 0
