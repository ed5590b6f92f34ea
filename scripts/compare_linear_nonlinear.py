#!/usr/bin/env python3
"""Floquet multipliers measured from nonlinear Exudyn runs against the predictions.

Cases (:data:`_link_oracle.decay_study.MULTIPLIER_CASES`): the complex pair at
Omega = 2pi (kp = 10, kd = 2), the paper's Table 3 gains at the four Omegas,
two deliberately wrong predictions at 8pi (gains +5 %, rigid reference) that
must fail, and the uncontrolled loop at 2pi with its growth run.  Writes
``multipliers_measured.json``, ``multipliers_measured.md`` and the figures
``multipliers_table3.png`` / ``multipliers_checks.png`` (complex plane, unit
circle, zoom on the dominant multiplier) to ``results/`` (or ``--out``).

``--transients`` also writes the older time-series comparison (hub-angle
error of the nonlinear runs against the linear response,
``linear_vs_nonlinear*``).  ``--quick``: 2 elements, h and h/2, the 8pi
cases only.

``--model-files``: the same measurement through the generic model-file path
(:func:`validation.multipliers.validate_model_multipliers`): the built-in
``single-link`` model file at the Table 3 gains, four Omegas (``--elements``,
default 4), and the built-in ``two-link`` arm at the tuned four gains of
:data:`TWO_LINK_TUNED` (2 elements per link), default steps
(:func:`~validation.multipliers.suggested_step`), rho_inf = 1; writes
``multipliers_model_files.json`` / ``.md`` / ``.png``.  With ``--quick``: the
single link at 8pi with 2 elements and h, h/2 only.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# the hand-derived link is the test suite's independent oracle (tests/_link_oracle)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


#: Tuned two-link gains (four-gain Taguchi tuning to rho_d = 0.3): Omega/pi -> ((kp1, kp2), (kd1, kd2)).
TWO_LINK_TUNED = {2: ((15.0, 7.1484), (8.9453, 1.4531)), 4: ((21.406, 6.1719), (7.8516, 1.8867))}


def model_file_study(out: Path, *, elements: int = 4, quick: bool = False) -> list:
    """Measured vs predicted multipliers through the model-file path (see the module docstring)."""
    from mbs_models.paper_data import TABLE3_PRINTED
    from validation.multipliers import MultiplierCheckConfig, validate_model_multipliers
    from validation.plots import plot_multiplier_plane

    cases = [("single-link", k, (kp,), (kd,), {"elements": 2 if quick else elements})
             for k, _rho, kp, kd, _ in TABLE3_PRINTED if not quick or k == 8]
    if not quick:
        cases += [("two-link", k, kp, kd, {"elements": 2}) for k, (kp, kd) in TWO_LINK_TUNED.items()]
    config = MultiplierCheckConfig(step=None, amplitude=None, refinements=2)  # two levels give no verdict
    rows, results = [], []
    for model, k, kp, kd, opts in cases:
        tic = time.process_time()
        r = validate_model_multipliers(model, k * math.pi, kp=list(kp), kd=list(kd), config=config, **opts)
        d = r.to_dict()
        d.update({"case": f"{model}, {k}pi", "elements_per_link": opts["elements"],
                  "cpu_seconds": time.process_time() - tic})
        rows.append(d)
        results.append((f"{model}, Ω = {k}π", r))
    lines = [
        "# Measured vs predicted multipliers through the model-file path",
        "",
        "Nonlinear Exudyn runs (drives released, feed-forward + PD inside Exudyn, perturbations on the "
        "constraints), generalised-α ρ∞ = 1, steps h, h/2, h/4 from validation.multipliers.suggested_step, "
        "Newton on the increment (1e-10); bar = GCI step error + amplitude error + the prediction's "
        "propagator error (GCI of its step doublings).",
        "",
        "| case | el. | mode | predicted | measured | abs. error | rel. error | bar | step err. | ampl. err. | "
        "pred. err. | resolved | agrees | h (s) | CPU (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for d in rows:
        for m in d["multipliers"]:
            c = lambda z: "n/a" if z is None else f"{z[0]:+.7f}{z[1]:+.7f}i"  # noqa: E731
            g = lambda x: "n/a" if x is None else f"{x:.2e}"  # noqa: E731
            lines.append(
                f"| {d['case']} | {d['elements_per_link']} | {m['mode']} | {c(m['predicted'])} | {c(m.get('measured'))} | "
                f"{g(m.get('abs_error'))} | {g(m.get('relative_error'))} | {g(m.get('error_bar'))} | "
                f"{g(m.get('step_error'))} | {g(m.get('amplitude_error'))} | {g(m.get('prediction_error'))} | "
                f"{'yes' if m.get('step_converged') else 'NO'} | {'yes' if m.get('agrees') else 'no'} | "
                f"{d['steps'][0]:.3g} | {d['cpu_seconds']:.0f} |")
    (out / "multipliers_model_files.json").write_text(json.dumps(rows, indent=2))
    (out / "multipliers_model_files.md").write_text("\n".join(lines) + "\n")
    plot_multiplier_plane([r for _, r in results], out / "multipliers_model_files.png",
                          titles=[t for t, _ in results], suptitle="Model-file path: measured vs predicted multipliers")
    print("\n".join(lines))
    return rows


def main(argv=None) -> int:
    from tqdm import tqdm

    from validation.multipliers import MultiplierCheckConfig
    from validation.plots import plot_multiplier_plane
    from _link_oracle.decay_study import MULTIPLIER_CASES, multiplier_markdown, multiplier_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results", help="output folder (default results/)")
    ap.add_argument("--elements", type=int, default=4, help="ANCF elements (default 4)")
    ap.add_argument("--refinements", type=int, default=2, help="step halvings (default 2: h, h/2, h/4)")
    ap.add_argument("--step", type=float, default=None,
                    help="coarsest step (default: validation.multipliers.suggested_step, at most 1e-3 s)")
    ap.add_argument("--quick", action="store_true", help="2 elements, h and h/2, the 8pi cases only")
    ap.add_argument("--transients", action="store_true", help="also the time-series comparison (slow)")
    ap.add_argument("--model-files", action="store_true",
                    help="only the model-file path: single-link (Table 3, four Omegas) and two-link (tuned gains)")
    args = ap.parse_args(argv)
    if args.model_files:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        model_file_study(out, elements=args.elements, quick=args.quick)
        return 0
    elements, refinements = args.elements, args.refinements
    cases = MULTIPLIER_CASES
    if args.quick:
        elements, refinements = 2, 2  # three step levels: two give no verdict
        cases = [c for c in MULTIPLIER_CASES if c[1] == 8]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tic = time.perf_counter()
    config = MultiplierCheckConfig(step=args.step, refinements=refinements)
    with tqdm(total=len(cases), desc="multipliers", disable=None) as bar:
        def step(label: str) -> None:
            bar.set_postfix_str(label)
            bar.update(1)

        rows = multiplier_study(cases=cases, elements=elements, config=config, progress=step)
    figures = []
    t3 = [r for r in rows if r.name == "Table 3"]
    if t3:
        path = out / "multipliers_table3.png"
        plot_multiplier_plane([r.result for r in t3], path,
                              titles=[f"Ω = {r.omega_over_pi}π, Table 3: kp = {r.result.info['kp']:.5g}, "
                                      f"kd = {r.result.info['kd']:.5g}" for r in t3],
                              suptitle=f"Measured (nonlinear Exudyn, {elements} elements) vs predicted multipliers")
        figures.append(str(path))
    rest = [r for r in rows if r.name != "Table 3"]
    if rest:
        path = out / "multipliers_checks.png"
        plot_multiplier_plane([r.result for r in rest], path,
                              titles=[f"Ω = {r.omega_over_pi}π, {r.name}" for r in rest],
                              suptitle="Complex pair, deliberately wrong predictions, uncontrolled loop")
        figures.append(str(path))
    data = {
        "elements": elements,
        "steps": list(config.steps),
        "wall_time": time.perf_counter() - tic,
        "figures": [Path(f).name for f in figures],
        "rows": [r.to_dict() for r in rows],
    }
    (out / "multipliers_measured.json").write_text(json.dumps(data, indent=2))
    md = multiplier_markdown(rows, elements=elements, figures=figures)
    (out / "multipliers_measured.md").write_text(md)
    print(md)
    if args.transients:
        _transients(out, elements=8 if not args.quick else 2, quick=args.quick)
    return 0


def _transients(out: Path, *, elements: int, quick: bool) -> None:
    """The time-series comparison (nonlinear hub-angle error vs the linear response)."""
    from _link_oracle.decay_plots import plot_validation_figure
    from _link_oracle.decay_study import CASES, compare_linear_nonlinear, comparison_markdown

    kwargs = dict(elements=elements, periods=5, omegas=(2, 4, 6, 8))
    if quick:
        kwargs.update(periods=3, omegas=(2,), samples=16)
    rows = compare_linear_nonlinear(**kwargs)
    figures = []
    for k in kwargs["omegas"]:
        sel = [r for r in rows if r.omega_over_pi == k]
        path = out / f"linear_vs_nonlinear_omega{k}pi.png"
        plot_validation_figure(
            [r.result for r in sel], path,
            titles=[f"{r.case}: kp = {r.result.kp:.4g}, kd = {r.result.kd:.4g}, δ = {r.result.perturbation:.3g} rad/s"
                    for r in sel],
            suptitle=f"Ω = {k}π: nonlinear Exudyn ({elements} elements) vs linearised Exudyn",
        )
        figures.append(str(path))
    (out / "linear_vs_nonlinear.json").write_text(json.dumps(
        {"elements": elements, "periods": kwargs["periods"], "cases": list(CASES),
         "rows": [r.to_dict() for r in rows]}, indent=2))
    (out / "linear_vs_nonlinear.md").write_text(
        comparison_markdown(rows, elements=elements, periods=kwargs["periods"], figures=figures))


if __name__ == "__main__":
    raise SystemExit(main())
