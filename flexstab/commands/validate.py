"""``flexstab validate``: Floquet multipliers measured from nonlinear Exudyn runs vs the prediction.

The command line of :func:`flexstab.validation_runs.validate_multipliers` (its table, JSON and
``--out`` files).  The one-period map of the nonlinear closed loop (feed-forward + PD, started
from the periodic orbit perturbed along the predicted Floquet vectors) is
measured with generalised-alpha at ``rho_inf = 1`` and steps ``h, h/2, h/4``;
its eigenvalues are compared with the predicted multipliers in modulus and
phase within the measurement's error bar (:mod:`validation.multipliers`).
With ``--full-map`` (model files) the whole one-period map is also measured
from random constraint-consistent perturbations (:mod:`validation.full_map`);
a resolved slow multiplier without a predicted partner is a failed check.

Gains: ``--kp``/``--kd`` if given (a missing one is 0; one value per drive,
comma-separated, or one value for all); if neither is given, the study's rule
(:func:`flexstab.validation_runs.resolve_gains`): the paper's printed Table 3 gains for
the paper's manipulator at one of the paper's Omegas (2pi, 4pi, 6pi, 8pi),
otherwise the gains Taguchi tunes on the reduced model of the configured
manipulator at that Omega to the configured target (the output says which).
The printed gains belong to the paper's link only.

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

from flexstab.options import dump_json, ensure_out_dir, gains_as_lists, parse_omega, result_output
from flexstab.validation_runs import resolve_gains

__all__ = ["register", "run", "validate_options", "validation_report", "resolve_gains"]


def register(sub) -> None:
    p = sub.add_parser(
        "validate",
        help="Floquet multipliers measured from nonlinear Exudyn runs vs the prediction",
        description=(
            "Measure the one-period map of the nonlinear Exudyn closed loop on the subspace of the "
            "predicted dominant multipliers (perturbed-minus-reference runs, generalised-alpha with "
            "rho_inf = 1 at h, h/2, h/4) and compare its eigenvalues with the prediction in modulus and "
            "phase within the measurement's error bar; report the distance to the reduced model and "
            "to the rigid-reference linearisation."
        ),
    )
    p.add_argument("--model", default="exudyn",
                   help="'exudyn' (default: the paper's link, the built-in model file single-link with --config's "
                        "manipulator and the paper's gains), a model file PATH.py or a built-in model name")
    p.add_argument("--config", metavar="FILE", help="TOML file describing the manipulator (see README)")
    p.add_argument("--omega", default=None, metavar="W",
                   help="frequency of the fundamental motion, rad/s or like '2pi' (default: config, else 2pi)")
    p.add_argument("--kp", default=None, help="proportional gain(s) (N m/rad), comma-separated per drive")
    p.add_argument("--kd", default=None, help="derivative gain(s) (N m s/rad), comma-separated per drive")
    p.add_argument("--elements", default=None,
                   help="ANCF elements (default 4 for the built-in link; built-in model files: passed to their "
                        "build, per link for two-link; default: the model's own)")
    p.add_argument("--samples", default=None,
                   help="orbit / linearisation samples per period (default 32: the runs' feed-forward is "
                        "interpolated from the samples)")
    p.add_argument("--step", default=None,
                   help="coarsest generalised-alpha step in s (default: T/n chosen so that strongly damped modes "
                        "get no spurious multiplier, see validation.multipliers.suggested_step)")
    p.add_argument("--spectral-radius", default="1",
                   help="generalised-alpha rho_inf (default 1: no numerical damping; see validation.multipliers)")
    p.add_argument("--refinements", default="2", help="step halvings for the error bar (default 2: h, h/2, h/4; 1 gives a bar but no verdict, "
                        "two levels show no convergence order)")
    p.add_argument("--amplitude", default=None,
                   help="perturbation energy as a hub-velocity kick in rad/s (default 1e-2)")
    p.add_argument("--compare", default="2", help="number of multipliers compared (default 2; pairs kept whole)")
    p.add_argument("--growth-periods", default=None,
                   help="periods of the multi-period growth run (default: 3 if the prediction is unstable, else 0)")
    p.add_argument("--predict-reference", choices=("periodic", "rigid"), default="periodic",
                   help="reference motion of the prediction under test: the periodic orbit (rigid: no longer "
                        "available, exit 2)")
    p.add_argument("--full-map", action="store_true",
                   help="also measure the whole one-period map from random constraint-consistent perturbations "
                        "(model files; Newmark/trapezoidal, index-2 constraints; see docs/validation.md) and reject "
                        "a prediction that misses a slow mode it finds (exit 1)")
    p.add_argument("--full-map-step", default=None,
                   help="coarsest step of the full-map runs in s (default: the same rule as --step)")
    p.add_argument("--workers", default=None, help="worker processes for the full-map runs (default: 2; 1: serial)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="also write validation.json and validation.png (complex plane) to DIR")
    p.epilog = (
        "Gains: if neither --kp nor --kd is given, the paper's Table 3 gains for the paper's manipulator at "
        "2pi, 4pi, 6pi or 8pi, otherwise the gains Taguchi tunes on the reduced model (as flexstab study); "
        "if one is given, a missing gain is 0."
    )
    p.set_defaults(func=run)


def _number(name: str, text: Optional[str], *, integer: bool = False) -> Optional[float]:
    """``text`` as a finite number (an integer with ``integer``); ``None`` stays ``None``.  The ranges are
    checked by :func:`flexstab.validation_runs.check_validate_options`."""
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
    return int(value) if integer else value


def _gains(name: str, text: Optional[str]) -> Optional[tuple]:
    """Comma-separated gains (one per drive)."""
    if text is None:
        return None
    return tuple(_number(name, s.strip()) for s in str(text).split(","))


def validate_options(args: argparse.Namespace) -> "ValidateOptions":
    """The :class:`~flexstab.validation_runs.ValidateOptions` of the parsed command line (numbers parsed
    here rather than by ``argparse`` so that every bad value ends as one line and exit code 2)."""
    from flexstab.validation_runs import ValidateOptions

    ints = {flag: _number(flag, getattr(args, flag.replace("-", "_")), integer=True)
            for flag in ("elements", "samples", "refinements", "compare", "growth-periods", "workers")}
    return ValidateOptions(
        model=args.model, omega=parse_omega(args.omega) if args.omega is not None else None,
        kp=_gains("kp", args.kp), kd=_gains("kd", args.kd), elements=ints["elements"], samples=ints["samples"],
        step=_number("step", args.step), spectral_radius=_number("spectral-radius", args.spectral_radius),
        refinements=ints["refinements"], amplitude=_number("amplitude", args.amplitude), compare=ints["compare"],
        growth_periods=ints["growth-periods"], predict_reference=args.predict_reference,
        full_map=bool(getattr(args, "full_map", False)), full_map_step=_number("full-map-step", args.full_map_step),
        workers=ints["workers"])


def validation_report(args: argparse.Namespace):
    """``flexstab validate``: :func:`flexstab.validation_runs.validate_multipliers` of the command line (its
    checks first, then the configuration); return ``(dict, MultiplierValidation)``."""
    from flexstab.validation_runs import CONFIG_FOR_MODEL_FILE, check_validate_options, validate_multipliers

    if args.model != "exudyn" and args.config is not None:
        raise ValueError(CONFIG_FOR_MODEL_FILE)
    opts = validate_options(args)
    check_validate_options(opts)  # every option before the configuration and the numerical imports
    cfg = None
    if opts.model == "exudyn":
        from flexstab.config import load_config

        cfg = load_config(args.config)
    if args.out is not None:
        ensure_out_dir(args.out)
    res = validate_multipliers(opts, cfg)
    return res.report, res.measurement


def _c(z) -> str:
    if z is None:
        return "n/a"
    re_, im = z
    return f"{re_:+.7f}{im:+.7f}i"


def _text(d: dict) -> str:
    def f(x, fmt=".3g"):
        return "n/a" if x is None else format(x, fmt)

    steps = ", ".join(f"{h:g}" for h in d["steps"])
    if d.get("model") == "exudyn":
        what = f"{d['elements']} elements"
    else:
        what = f"model {d['model']}" + (f", {d['elements']} elements" if d.get("elements") else "")
    gains = ", ".join(f"{g['name']}: kp = {g['kp']:.6g}, kd = {g['kd']:.6g}" for g in d.get("drives", [])) or "no drives"
    lines = [
        f"nonlinear multiplier measurement (Exudyn, {what}, {d['integrator']}, h = {steps} s)",
        f"omega = {d['omega']:.6g} rad/s ({d['omega_over_pi']:.6g} pi), T = {d['period']:.6g} s",
        f"{gains}  ({d['gains_source']})",
        f"prediction under test: {d['prediction']}",
        "",
        f"{'mode':<10} {'predicted':>26} {'measured':>26} {'|error|':>9} {'bar':>9} {'step':>9} {'ampl.':>9} {'agrees':>6}",
    ]
    for m in d["multipliers"]:
        lines.append(
            f"{m['mode']:<10} {_c(m['predicted']):>26} {_c(m.get('measured')):>26} {f(m.get('abs_error')):>9} "
            f"{f(m.get('error_bar')):>9} {f(m.get('step_error')):>9} {f(m.get('amplitude_error')):>9} "
            f"{('yes' if m.get('agrees') else 'no'):>6}"
        )
    a = d["amplitude_check"]
    lines += [
        "",
        f"amplitude check (a = {a['amplitude']:g} -> {a['half']:g}, h = {a['step']:g} s): change "
        f"{', '.join(f(c) for c in (a['change'] or []))} -> {'passed' if a['passed'] else 'NOT passed'}",
        f"step convergence: observed ratio {', '.join(f(q) for q in (d['observed_ratio'] or []))}"
        f" ({'converging' if d['step_converged'] else 'NOT converging'}); measured = Richardson extrapolation"
        f" when three levels converge, else the finest step",
    ]
    for alt in d["alternatives"]:
        verdict = ("no measurement" if alt["distance"] is None
                   else ("consistent with" if alt["consistent"] else "excluded by") + " the measurement")
        lines.append(f"alternative: {alt['name']}: distance {f(alt['distance'])} -> {verdict}")
    for u in d.get("unresolved", []):
        lines.append(f"not resolved (no verdict): {u['mode']} {_c(u['predicted'])}, levels "
                     + ", ".join(_c(z) for z in u["levels"]) + f" -- criterion: {d['resolved_criterion']}")
    lines.append(f"agrees: {'yes' if d['agrees'] else 'no'} (dominant: {'yes' if d['agrees_dominant'] else 'no'}; "
                 f"every compared multiplier: {'yes' if d.get('agrees_all') else 'no'}); "
                 f"the measurement confirms: {', '.join(d['confirms']) or 'none'}")
    g = d.get("growth")
    if g:
        lines.append(
            f"growth run: per-period ratios {', '.join(f(r, '.5g') for r in g['ratios'] or [])}; inside the linear range "
            f"{f(g['measured_growth'], '.6g')} vs predicted {f(g['predicted'], '.6g')}; "
            + (f"linear range left at t = {g['linear_range_left_at']:.4g} s" if g['linear_range_left_at'] is not None
               else "linear range not left")
            + (f"; DIVERGED: {g['reason']}" if g["diverged"] else "")
        )
    if d["diverged"]:
        lines.append(f"DIVERGED at t = {f(d['diverged_at'], '.4g')} s: {d['reason']}")
    fm = d.get("full_map")
    if fm:
        lines.append(f"full one-period map ({fm['n_perturbations']} random perturbations, {fm['integrator']}, "
                     f"h = {', '.join(f'{h:g}' for h in fm['steps'])} s): slowest multipliers")
        for row in fm["partners"]:
            partner = (f"predicted {row['predicted']:.6f} ({row['mode']})" if row["predicted"] is not None
                       else "no predicted partner")
            state = ("not resolved (no verdict)" if not row["resolved"]
                     else ("agrees" if row["agrees"] else "NO PREDICTED PARTNER within the bars"))
            lines.append(f"  |mu| = {row['modulus']:.6f} +- {f(row['error_bar'])}: {partner} -> {state}")
        lines.append("full map: " + ("agrees (every resolved slow multiplier predicted)" if fm["agrees"] else
                                     f"REJECTS the prediction: {len(fm['unmatched'])} resolved slow multiplier(s) "
                                     "without a predicted partner" if fm["unmatched"] else "no verdict"))
    t = d["timings"]
    lines.append(f"time: prediction {t.get('prediction', 0):.2f} s, alternatives {t.get('alternatives', 0):.2f} s, "
                 f"measurement {t.get('measurement', 0):.2f} s, total {t.get('total', 0):.2f} s")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from flexstab.progress import progress_log

    with progress_log("validation", "validate"):  # the measurement's steps, one line each, on stderr
        d, res = validation_report(args)
    gains_as_lists(d)
    if args.out is not None:
        from validation.plots import plot_multiplier_plane

        out = Path(args.out)
        (out / "validation.json").write_text(json.dumps(d, indent=2))
        gains = ", ".join(f"{g['name']}: kp = {g['kp']:.4g}, kd = {g['kd']:.4g}" for g in d.get("drives", []))
        plot_multiplier_plane([res], out / "validation.png",
                              titles=[f"{d['model']}, Omega = {d['omega_over_pi']:.4g} pi" + (f", {gains}" if gains else "")])
    with result_output(args):
        if args.json:
            dump_json(d, sys.stdout)
        else:
            print(_text(d))
    from flexstab.checks import exit_code, validation_failures

    failures = validation_failures(d)
    for line in failures:
        print(f"flexstab validate: check failed: {line}", file=sys.stderr)
    return exit_code(failures)
