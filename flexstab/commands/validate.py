"""``flexstab validate``: nonlinear Exudyn closed-loop run against the predicted multipliers.

Gains: ``--kp``/``--kd`` if given (a missing one is 0); if neither is given
and Omega is one of the paper's cases (2pi, 4pi, 6pi, 8pi), the paper's
printed Table 3 gains are used (and the output says so); otherwise the loop
is uncontrolled (``kp = kd = 0``).

Numbers are parsed here rather than by ``argparse`` so that every bad value
ends as one line and exit code 2.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Optional

from flexstab.config import load_config
from flexstab.options import dump_json, parse_omega

__all__ = ["register", "run", "validation_report", "resolve_gains"]


def register(sub) -> None:
    p = sub.add_parser(
        "validate",
        help="nonlinear Exudyn closed-loop run vs the predicted Floquet multipliers",
        description=(
            "Simulate the free-hub Exudyn model under feed-forward + PD from the periodic orbit "
            "with the hub velocity raised by the paper's 0.25 pi rad/s (Eqs. 26/35), measure the "
            "per-period decay of the perturbation and compare it with the dominant multipliers of "
            "the reduced model and of the Exudyn linearisation."
        ),
    )
    p.add_argument("--config", metavar="FILE", help="TOML file describing the manipulator (see README)")
    p.add_argument("--omega", default=None, metavar="W",
                   help="frequency of the fundamental motion, rad/s or like '2pi' (default: config, else 2pi)")
    p.add_argument("--kp", default=None, help="proportional gain (N m/rad); see the gain rule in --help")
    p.add_argument("--kd", default=None, help="derivative gain (N m s/rad)")
    p.add_argument("--elements", default=None, help="ANCF elements (default: config, else 8)")
    p.add_argument("--periods", default="5", help="periods to simulate (default 5)")
    p.add_argument("--perturbation", default=None,
                   help="hub-velocity perturbation in rad/s (default 0.25pi, paper Eqs. 26/35)")
    p.add_argument("--step", default="1e-3", help="generalised-alpha step in s (default 1e-3)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="also write validation.json and validation.png to DIR")
    p.epilog = (
        "Gains: if neither --kp nor --kd is given and Omega is 2pi, 4pi, 6pi or 8pi, the paper's "
        "Table 3 gains are used; otherwise a missing gain is 0."
    )
    p.set_defaults(func=run)


def _number(name: str, text: Optional[str], *, minimum: Optional[float] = None, integer: bool = False,
            strict: bool = False) -> Optional[float]:
    if text is None:
        return None
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"--{name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"--{name} must be finite, got {text!r}")
    if integer and value != int(value):
        raise ValueError(f"--{name} must be an integer, got {text!r}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"--{name} must be {'>' if strict else '>='} {minimum:g}, got {text!r}")
    return int(value) if integer else value


def resolve_gains(omega: float, kp: Optional[float], kd: Optional[float]) -> tuple[float, float, str]:
    """Gains to use and where they come from (see the module docstring)."""
    if kp is None and kd is None:
        from flexstab.paper_tables import TABLE3_PRINTED

        for k, _rho_d, kp3, kd3, _rho in TABLE3_PRINTED:
            if abs(omega - k * math.pi) <= 1e-9 * omega:
                return kp3, kd3, f"paper Table 3 gains for Omega = {k}pi"
        return 0.0, 0.0, "uncontrolled (no gains given, Omega not a Table 3 case)"
    return (kp or 0.0), (kd or 0.0), "command line"


def validation_report(args: argparse.Namespace):
    """Run the validation requested by ``args``; return ``(dict, ValidationResult)``."""
    from validation.closed_loop import PAPER_PERTURBATION, validate_closed_loop

    cfg = load_config(args.config)
    omega = parse_omega(args.omega) if args.omega is not None else cfg.omega
    kp = _number("kp", args.kp, minimum=0.0)
    kd = _number("kd", args.kd, minimum=0.0)
    elements = _number("elements", args.elements, minimum=1, integer=True)
    elements = cfg.elements if elements is None else elements
    periods = _number("periods", args.periods, minimum=1, integer=True)
    perturbation = _number("perturbation", args.perturbation)
    if perturbation is None:
        perturbation = PAPER_PERTURBATION
    if perturbation == 0.0:
        raise ValueError("--perturbation must be non-zero")
    step = _number("step", args.step, minimum=0.0, strict=True)
    if args.out is not None:
        out = Path(args.out)
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"cannot create output folder {out}: {exc.strerror or exc}") from None
    kp, kd, source = resolve_gains(omega, kp, kd)
    res = validate_closed_loop(
        cfg.manipulator, omega, kp, kd,
        elements=elements, periods=periods, perturbation=perturbation, step=step,
    )
    d = res.to_dict()
    d["gains_source"] = source
    return d, res


def _text(d: dict) -> str:
    def f(x, fmt=".6g"):
        return "n/a" if x is None else format(x, fmt)

    lines = [
        f"nonlinear validation (Exudyn, {d['elements']} elements, h = {d['step']:g} s)",
        f"omega = {d['omega']:.6g} rad/s ({d['omega_over_pi']:.6g} pi), T = {d['period']:.6g} s",
        f"kp = {d['kp']:.6g}, kd = {d['kd']:.6g}  ({d['gains_source']})",
        f"hub-velocity perturbation {d['perturbation']:.6g} rad/s, {d['periods_completed']}/{d['periods']} periods",
        "",
        f"{'k':>3}  {'|dq_a(kT)| rad':>15}  {'max|dq_a| rad':>14}  {'max|dw_tip| m':>14}  {'ref. drift rad':>14}",
    ]
    env = d["envelope"] or []
    for k, s in enumerate(d["stroboscopic"] or []):
        e = env[k] if k < len(env) else None
        te = d["tip_envelope"][k] if k < len(env) else None
        dr = d["reference_drift"][k] if k < len(env) else None
        lines.append(f"{k:>3}  {f(s, '15.4e')}  {f(e, '14.4e'):>14}  {f(te, '14.4e'):>14}  {f(dr, '14.4e'):>14}")
    lines += [
        "",
        f"measured ratio per period   {f(d['measured_ratio_per_period'])}  (stroboscopic fit, periods {d['fit_periods']});"
        f" envelope fit {f(d['measured_ratio_envelope'])}",
        f"predicted, Exudyn lin.      {f(d['predicted_multiplier_exudyn'])}  ({d['predicted_mode_exudyn']} mode)"
        f"  -> relative difference {f(d['relative_error_exudyn'], '+.2%') if d['relative_error_exudyn'] is not None else 'n/a'}",
        f"predicted, reduced model    {f(d['predicted_multiplier_reduced'])}"
        f"  -> relative difference {f(d['relative_error_reduced'], '+.2%') if d['relative_error_reduced'] is not None else 'n/a'}",
        f"last per-period ratio       {f(d['last_ratio'])};"
        f" linear response, same fit {f(d['linear_ratio_per_period'])}",
        f"agreement within {d['agreement_tolerance']:.0%}: {'yes' if d['agrees'] else 'no'}",
    ]
    if d["linear_range_left_at"] is not None:
        lines.append(
            f"linear range left at t = {d['linear_range_left_at']:.4g} s (period {d['linear_range_left_period']}):"
            f" |dq_a| or reference drift > {d['linear_range_angle']:g} rad; later periods not fitted"
        )
    if d["diverged"]:
        lines.append(f"DIVERGED at t = {f(d['diverged_at'], '.4g')} s: {d['reason']}")
    t = d["timings"]
    lines.append(
        f"time: Exudyn Floquet {t.get('exudyn_floquet', 0):.2f} s, simulations {t.get('simulation_reference', 0):.2f}"
        f" + {t.get('simulation_perturbed', 0):.2f} s for {t.get('simulated_time', 0):.3g} s of model time, total {t.get('total', 0):.2f} s"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    d, res = validation_report(args)
    if args.out is not None:
        from validation.plots import plot_validation_figure

        out = Path(args.out)
        (out / "validation.json").write_text(json.dumps(d, indent=2))
        plot_validation_figure([res], out / "validation.png",
                               titles=[f"Omega = {d['omega_over_pi']:.4g} pi, kp = {d['kp']:.4g}, kd = {d['kd']:.4g}"])
    if args.json:
        dump_json(d, sys.stdout)
    else:
        print(_text(d))
    return 0
