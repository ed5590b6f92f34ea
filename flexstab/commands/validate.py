"""``flexstab validate``: Floquet multipliers measured from nonlinear Exudyn runs vs the prediction.

The one-period map of the nonlinear closed loop (feed-forward + PD, started
from the periodic orbit perturbed along the predicted Floquet vectors) is
measured with generalised-alpha at ``rho_inf = 1`` and steps ``h, h/2, h/4``;
its eigenvalues are compared with the predicted multipliers in modulus and
phase within the measurement's error bar (:mod:`validation.multipliers`).
With ``--full-map`` (model files) the whole one-period map is also measured
from random constraint-consistent perturbations (:mod:`validation.full_map`);
a resolved slow multiplier without a predicted partner is a failed check.

Gains: ``--kp``/``--kd`` if given (a missing one is 0; one value per drive,
comma-separated, or one value for all); if neither is given, the study's rule
(:func:`flexstab.study` reference gains): the paper's printed Table 3 gains for
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

__all__ = ["register", "run", "validation_report", "resolve_gains"]


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


def _gains(name: str, text: Optional[str]) -> Optional[list]:
    """Comma-separated non-negative gains (one per drive)."""
    if text is None:
        return None
    parts = [s for s in str(text).split(",")]
    return [_number(name, s.strip(), minimum=0.0) for s in parts]


def resolve_gains(omega: float, kp: Optional[float], kd: Optional[float], cfg=None) -> tuple[float, float, str]:
    """Gains to use and where they come from (see the module docstring).

    ``cfg`` (a :class:`~flexstab.config.StudyConfig`, default the paper's manipulator) decides
    whether the printed Table 3 gains apply and gives the target and ranges of the tuning.
    """
    if kp is None and kd is None:
        from flexstab.config import StudyConfig
        from flexstab.paper_tables import is_paper_manipulator
        from mbs_models.paper_data import table3_gains

        cfg = cfg if cfg is not None else StudyConfig()
        hit = table3_gains(omega)
        if hit is not None and is_paper_manipulator(cfg.manipulator):
            k, kp3, kd3 = hit
            return kp3, kd3, f"paper Table 3 gains for Omega = {k}pi"
        from mbs_models.reduced import ReducedModel
        from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

        res = taguchi_tune(GainObjective(ReducedModel(omega, params=cfg.manipulator)),
                           TuningConfig(target=cfg.target, kp_range=cfg.kp_range, kd_range=cfg.kd_range))
        return res.kp, res.kd, (f"Taguchi on the reduced model (no gains given; rho_d = {cfg.target:g}, "
                                f"max|rho| = {res.spectral_radius:.5f}, {res.status})")
    return (kp or 0.0), (kd or 0.0), "command line"


def validation_report(args: argparse.Namespace):
    """Run the validation requested by ``args``; return ``(dict, MultiplierValidation)``."""
    if args.model != "exudyn":
        return _model_file_report(args)
    if getattr(args, "full_map", False):
        raise ValueError("--full-map applies to model files (e.g. --model single-link), not to --model exudyn")
    # every argument is checked before the numerical imports and the configuration
    omega = parse_omega(args.omega) if args.omega is not None else None
    kps, kds = _gains("kp", args.kp), _gains("kd", args.kd)
    for nm, g in (("kp", kps), ("kd", kds)):
        if g is not None and len(g) != 1:
            raise ValueError(f"--{nm}: the built-in single link has one drive (hub), got {len(g)} values")
    kp = kps[0] if kps else None
    kd = kds[0] if kds else None
    elements = _number("elements", args.elements, minimum=1, integer=True)
    elements = 4 if elements is None else elements
    samples = _number("samples", args.samples, minimum=4, integer=True) if args.samples is not None else None
    if samples is not None and samples % 2:
        raise ValueError(f"--samples must be even, got {args.samples!r}")
    step = _number("step", args.step, minimum=0.0, strict=True) if args.step is not None else None
    refinements = _number("refinements", args.refinements, minimum=0, integer=True)
    if refinements > 4:
        raise ValueError(f"--refinements must be <= 4, got {args.refinements!r}")
    amplitude = _number("amplitude", args.amplitude, minimum=0.0, strict=True) if args.amplitude is not None else None
    compare = _number("compare", args.compare, minimum=1, integer=True)
    growth = _number("growth-periods", args.growth_periods, minimum=0, integer=True)
    spectral_radius = _spectral_radius(args)
    from flexstab.config import load_config

    cfg = load_config(args.config)
    omega = cfg.omega if omega is None else omega
    if step is not None and step >= 2 * math.pi / omega:
        raise ValueError(f"--step must be smaller than the period T = {2 * math.pi / omega:.6g} s, got {args.step!r}")
    if args.predict_reference != "periodic":
        raise ValueError("--predict-reference rigid is no longer available: the prediction is the linearisation "
                         "about the periodic orbit (the rigid reference's distance is in docs/validation.md)")
    if args.out is not None:
        ensure_out_dir(args.out)
    from flexstab.options import resolve_model_definition
    from mbs_models.reduced import ReducedModel
    from stability import floquet
    from validation.multipliers import (MODEL_SAMPLES, MultiplierCheckConfig, prediction_from_multipliers,
                                        validate_model_multipliers)

    kp, kd, source = resolve_gains(omega, kp, kd, cfg)
    if growth is None:
        growth = 3 if (kp == 0.0 and kd == 0.0) else 0
    config = MultiplierCheckConfig(compare=compare, step=step, refinements=refinements, amplitude=amplitude,
                                   growth_periods=growth, spectral_radius=spectral_radius)
    # the paper's link is the built-in model file single-link with the configured manipulator
    definition, options = resolve_model_definition(args.model, cfg, elements)
    reduced = floquet(ReducedModel(omega=omega, kp=kp, kd=kd, params=cfg.manipulator))
    res = validate_model_multipliers(definition, omega, kp=kp, kd=kd,
                                     samples=MODEL_SAMPLES if samples is None else samples, config=config,
                                     alternatives=[prediction_from_multipliers("reduced model", reduced.multipliers)],
                                     **options)
    d = res.to_dict()
    d["model"] = args.model
    d["elements"] = elements
    d["gains_source"] = source
    return d, res


def _spectral_radius(args: argparse.Namespace) -> float:
    rho = _number("spectral-radius", args.spectral_radius, minimum=0.0)
    if rho > 1.0:
        raise ValueError(f"--spectral-radius must be in [0, 1], got {args.spectral_radius!r}")
    return rho


def _model_file_report(args: argparse.Namespace):
    """``--model PATH.py`` (or a built-in model name): the generic path."""
    if args.config is not None:
        raise ValueError("--config describes the built-in manipulator; it does not apply to a model file")
    if args.predict_reference != "periodic":
        raise ValueError("--predict-reference rigid is no longer available: the prediction is the linearisation "
                         "about the periodic orbit")
    # every argument is checked before the numerical imports and the model file
    from flexstab.options import check_model_arg, is_model_file

    check_model_arg(args.model)
    options: dict = {}
    if args.elements is not None:
        if is_model_file(args.model):
            raise ValueError("--elements applies to the built-in models only (a model file sets its own mesh)")
        options["elements"] = _number("elements", args.elements, minimum=1, integer=True)
    omega = parse_omega(args.omega) if args.omega is not None else 2 * math.pi
    T = 2 * math.pi / omega
    kps, kds = _gains("kp", args.kp), _gains("kd", args.kd)
    samples = (_number("samples", args.samples, minimum=4, integer=True) if args.samples is not None else None)
    if samples is not None and samples % 2:
        raise ValueError(f"--samples must be even, got {args.samples!r}")
    step = _number("step", args.step, minimum=0.0, strict=True) if args.step is not None else None
    if step is not None and step >= T:
        raise ValueError(f"--step must be smaller than the period T = {T:.6g} s, got {args.step!r}")
    refinements = _number("refinements", args.refinements, minimum=0, integer=True)
    if refinements > 4:
        raise ValueError(f"--refinements must be <= 4, got {args.refinements!r}")
    amplitude = _number("amplitude", args.amplitude, minimum=0.0, strict=True) if args.amplitude is not None else None
    compare = _number("compare", args.compare, minimum=1, integer=True)
    growth = _number("growth-periods", args.growth_periods, minimum=0, integer=True) or 0
    spectral_radius = _spectral_radius(args)
    full_step = _number("full-map-step", args.full_map_step, minimum=0.0, strict=True) \
        if getattr(args, "full_map_step", None) is not None else None
    if full_step is not None and full_step >= T:
        raise ValueError(f"--full-map-step must be smaller than the period T = {T:.6g} s, got {args.full_map_step!r}")
    workers = _number("workers", getattr(args, "workers", None), minimum=1, integer=True) \
        if getattr(args, "workers", None) is not None else 2
    if args.out is not None:
        ensure_out_dir(args.out)
    from mbs_models.model_file import resolve_model
    from validation.multipliers import MODEL_SAMPLES, MultiplierCheckConfig, validate_model_multipliers

    definition = resolve_model(args.model, **options)
    samples = MODEL_SAMPLES if samples is None else samples
    config = MultiplierCheckConfig(compare=compare, step=step, refinements=refinements, amplitude=amplitude,
                                   growth_periods=growth, spectral_radius=spectral_radius)
    res = validate_model_multipliers(definition, omega, kp=kps if kps else 0.0, kd=kds if kds else 0.0,
                                     samples=samples, config=config)
    d = res.to_dict()
    d["gains_source"] = "command line" if (kps or kds) else "none given (0 for every drive)"
    d.setdefault("elements", definition.options.get("elements"))
    if getattr(args, "full_map", False):
        d["full_map"] = _full_map(args.model, options, omega, kps, kds, samples, full_step, refinements,
                                  None if args.amplitude is None else amplitude, workers)
    return d, res


def _full_map(model, options, omega, kps, kds, samples, step, refinements, amplitude, workers) -> dict:
    """The ``full_map`` block: :func:`validation.full_map.measure_model_full_map` against the linearisation."""
    from flexstab.executor import make_executor
    from linearize.analysis import analyze
    from mbs_models.console import exudyn_console
    from validation.full_map import FullMapConfig, full_map_report, measure_model_full_map

    cfg = FullMapConfig(step=step, refinements=max(refinements, 2), amplitude=amplitude)
    kp, kd = (kps if kps else 0.0), (kds if kds else 0.0)
    with make_executor("process" if workers > 1 else "serial", max_workers=workers) as ex:
        result, runner = measure_model_full_map(model, omega, kp, kd, samples=samples, config=cfg,
                                                executor=None if workers == 1 else ex, chunks=workers, **options)
    with exudyn_console(True):
        analysis = analyze(runner.definition, omega, kp=kp, kd=kd, samples=samples, orbit=runner.orbit)
    return full_map_report(result, analysis)


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
