"""The whole study on one manipulator, as one command (``flexstab study``).

Stages, each writing its JSON beside the report so that every number in the
report can be traced to a file:

1. ``table2``  -- Floquet multipliers of the uncontrolled reduced model (paper Table 2);
2. ``table3``  -- Taguchi tuning of the reduced model to rho_d (paper Table 3);
3. ``charts``  -- max|rho| over the gain plane (with the Taguchi path) and against Omega;
4. ``transients`` -- linear transient responses (paper Figs. 2-9);
5. ``exudyn``  -- the Exudyn ANCF model: periodic orbit, linearisation, Floquet
   with the tuned gains, Taguchi tuning on the Exudyn linearisation;
6. ``validation`` -- nonlinear Exudyn simulations of the tuned closed loop
   against the predicted multipliers.

Stages 5-6 need the Exudyn layer; if a stage fails, the report says so and
names the error instead of the study crashing.
"""
from __future__ import annotations

import html
import json
import logging
import math
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from flexstab.config import StudyConfig

__all__ = ["StudyOptions", "StudyResult", "run_study", "STAGES"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StudyOptions:
    """Options of :func:`run_study`.

    Attributes
    ----------
    out : Path
        Output folder (created).
    quick : bool
        Fewer cases and coarser grids (the ``--quick`` mode, < 60 s).
    stages : tuple of str
        Which stages to run (default all of :data:`STAGES`).
    progress : bool
        Show tqdm progress bars.
    scheduler : str, optional
        Dask scheduler address for the chart sweep.
    """

    out: Path = Path("results")
    quick: bool = False
    stages: tuple[str, ...] = ()
    progress: bool = True
    scheduler: Optional[str] = None


@dataclass(frozen=True)
class StudyResult:
    """Where the report went and what each stage produced (or why it failed)."""

    out: Path
    report_md: Path
    report_html: Path
    stages: dict
    elapsed: float


# ----------------------------------------------------------------------------- stages
def _omegas(cfg: StudyConfig, quick: bool) -> list[int]:
    return [2] if quick else [2, 4, 6, 8]


def _stage_table2(cfg: StudyConfig, opts: StudyOptions) -> dict:
    from flexstab.paper_tables import table2_markdown, table2_rows

    rows = table2_rows(params=cfg.manipulator)
    (opts.out / "table2.json").write_text(json.dumps({"rows": rows}, indent=2))
    (opts.out / "table2.md").write_text(table2_markdown(rows))
    return {"json": "table2.json", "markdown": table2_markdown(rows), "figures": []}


def _stage_table3(cfg: StudyConfig, opts: StudyOptions) -> dict:
    from flexstab.paper_tables import TABLE3_PRINTED, table3_markdown, table3_rows

    cases = TABLE3_PRINTED[:1] if opts.quick else TABLE3_PRINTED
    rows = table3_rows(cases, params=cfg.manipulator)
    (opts.out / "table3.json").write_text(json.dumps({"rows": rows}, indent=2))
    return {"json": "table3.json", "markdown": table3_markdown(rows), "figures": [], "rows": rows}


def _stage_charts(cfg: StudyConfig, opts: StudyOptions) -> dict:
    import argparse

    from flexstab.commands.chart import make_charts

    args = argparse.Namespace(
        config=None, constants="auto", kp_range=list(cfg.kp_range), kd_range=list(cfg.kd_range),
        grid=15 if opts.quick else 41, target=cfg.target, omega_range=None,
        omega_points=31 if opts.quick else 121, kp=None, kd=None, no_taguchi=False, out=str(opts.out),
        scheduler=opts.scheduler, workers=None, omega=cfg.omega, model="reduced", elements=None,
    )
    s = make_charts(args, progress=opts.progress, cfg=cfg)
    name = [Path(f).name for f in s["figures"]]
    md = (
        f"max|rho| over the (kp, kd) plane at Omega = {cfg.omega / math.pi:.3g} pi with the |rho| = 1 and "
        f"rho_d = {cfg.target:g} contours and the Taguchi path; and max|rho| against Omega, uncontrolled "
        f"and with the tuned gains."
    )
    return {"json": Path(s["json"]).name, "markdown": md, "figures": name}


def _stage_transients(cfg: StudyConfig, opts: StudyOptions) -> dict:
    from flexstab.transients import make_transients

    doc = make_transients(opts.out, quick=opts.quick, params=cfg.manipulator)
    figs = [c["figure_file"] for c in doc["cases"]]
    lines = [
        "Homogeneous response (Eq. 25/33) of the linearised reduced model from x(0) = [0, 0, 0.25 pi, 0]",
        "(Eqs. 26/35), with the envelope rho1^(t/T) of the dominant multiplier. Measured growth per period:",
        "",
        "| figure | kp | kd | rho1 | last measured ratio | relative error |",
        "|---|---|---|---|---|---|",
    ]
    for c in doc["cases"]:
        lines.append(f"| {c['figure_file']} | {c.get('kp', 0):g} | {c.get('kd', 0):g} | {c['spectral_radius']:.6g} | "
                     f"{c['last_ratio']:.6g} | {c['last_ratio_relative_error']:+.2%} |")
    return {"json": "transients.json", "markdown": "\n".join(lines), "figures": figs}


def _stage_exudyn(cfg: StudyConfig, opts: StudyOptions) -> dict:
    """Exudyn model: orbit, linearisation, Floquet at the printed and tuned gains; Taguchi on it."""
    from flexstab.executor import make_executor
    from flexstab.paper_tables import TABLE3_PRINTED
    from mbs_models.exudyn_floquet import ExudynPlant, exudyn_floquet
    from mbs_models.reduced import ReducedModel
    from stability import floquet
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    cases = TABLE3_PRINTED[:1] if opts.quick else TABLE3_PRINTED
    elements = min(cfg.elements, 4) if opts.quick else cfg.elements
    rows = []
    with make_executor("process" if not opts.quick else "serial", max_workers=2) as ex:
        for k, rho_d, kp_p, kd_p, _ in cases:
            omega = k * math.pi
            ef = exudyn_floquet(cfg.manipulator, omega=omega, kp=kp_p, kd=kd_p, elements=elements)
            plant = ExudynPlant(ef.linearization.with_gains(0.0, 0.0))
            uncontrolled = plant.spectral_measure(0.0, 0.0)
            tcfg = TuningConfig(target=rho_d, kp_range=cfg.kp_range, kd_range=cfg.kd_range,
                                max_evaluations=100 if opts.quick else 300)
            tuned = taguchi_tune(GainObjective(plant), tcfg, executor=ex)
            reduced = floquet(ReducedModel(omega, kp_p, kd_p, cfg.manipulator)).spectral_radius
            rows.append({
                "omega": omega, "omega_over_pi": k, "elements": elements, "target": rho_d,
                "orbit_residual": float(ef.orbit.residual),
                "uncontrolled_dominant": uncontrolled,
                "printed_kp": kp_p, "printed_kd": kd_p,
                "printed_gains_dominant_exudyn": float(abs(ef.dominant_multiplier)),
                "printed_gains_dominant_mode": ef.dominant_mode,
                "printed_gains_dominant_reduced": reduced,
                "spectral_radius_all_modes": float(ef.floquet.spectral_radius),
                "undamped_multipliers": int(ef.undamped_count),
                "tuned_kp": tuned.kp, "tuned_kd": tuned.kd, "tuned_dominant": tuned.spectral_radius,
                "tuning_status": tuned.status, "tuning_evaluations": tuned.evaluations,
                "tuning_time_s": tuned.elapsed,
            })
    (opts.out / "exudyn.json").write_text(json.dumps({"rows": rows}, indent=2))
    md = [
        f"Exudyn ANCF model ({elements} elements), linearised by central differences along its T-periodic",
        "orbit; Floquet multipliers by the exponential-midpoint product (`magnus2`). 'dominant' = largest",
        "multiplier of the modes the paper's model has (hub, first bending); the axial and higher bending",
        "modes are undamped (no structural damping, as in the paper) and sit on the unit circle.",
        "",
        "| Omega | uncontrolled dominant | printed gains: Exudyn | reduced | all-modes max|rho| | Taguchi on Exudyn kp, kd | reached | evals |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        md.append(
            f"| {r['omega_over_pi']}pi | {r['uncontrolled_dominant']:.5f} | {r['printed_gains_dominant_exudyn']:.5f} "
            f"({r['printed_gains_dominant_mode']}) | {r['printed_gains_dominant_reduced']:.5f} | "
            f"{r['spectral_radius_all_modes']:.6f} | {r['tuned_kp']:.4f}, {r['tuned_kd']:.4f} | "
            f"{r['tuned_dominant']:.5f} ({r['tuning_status']}) | {r['tuning_evaluations']} |"
        )
    return {"json": "exudyn.json", "markdown": "\n".join(md), "figures": [], "rows": rows}


def _stage_validation(cfg: StudyConfig, opts: StudyOptions) -> dict:
    """Nonlinear Exudyn simulations of the tuned closed loops against the predicted multipliers.

    Gains: the Taguchi gains tuned on the Exudyn model (read from ``exudyn.json`` written by the
    ``exudyn`` stage, so the numbers are traceable), else the paper's printed Table 3 gains.
    """
    from flexstab.paper_tables import TABLE3_PRINTED
    from validation.closed_loop import validate_closed_loop

    src = opts.out / "exudyn.json"
    if src.exists():
        gains = [(r["omega_over_pi"], r["tuned_kp"], r["tuned_kd"], "Taguchi on Exudyn (exudyn.json)")
                 for r in json.loads(src.read_text())["rows"]]
    else:
        cases = TABLE3_PRINTED[:1] if opts.quick else TABLE3_PRINTED
        gains = [(k, kp, kd, "paper Table 3") for k, _, kp, kd, _ in cases]
    elements = min(cfg.elements, 4) if opts.quick else cfg.elements
    from validation.plots import plot_validation_figure

    rows = []
    results = []
    for k, kp, kd, source in gains:
        v = validate_closed_loop(cfg.manipulator, k * math.pi, kp, kd, elements=elements,
                                 periods=3 if opts.quick else 5)
        results.append(v)
        d = v.to_dict()
        d.update({"omega_over_pi": k, "gains_source": source})
        for key in ("times", "hub_error", "tip_error", "drift"):
            d.pop(key, None)
        rows.append(d)
    (opts.out / "validation.json").write_text(json.dumps({"rows": rows}, indent=2, default=float))
    fig = "validation_tuned_gains.png"
    plot_validation_figure(results, opts.out / fig,
                           titles=[f"Omega = {g[0]} pi: kp = {g[1]:.4g}, kd = {g[2]:.4g}" for g in gains],
                           suptitle="Nonlinear vs linearised Exudyn (tuned gains)")
    md = [
        f"Free-hub Exudyn model ({elements} elements) under feed-forward + PD, started from the periodic",
        "orbit with the hub velocity raised by 0.25 pi rad/s (Eqs. 26/35); the perturbation is the",
        "difference from the unperturbed closed loop, sampled once per period. Measured per-period ratio",
        "against the dominant multiplier predicted by the Exudyn linearisation and by the reduced model.",
        "",
        "| Omega | kp | kd | gains | measured ratio | predicted (Exudyn) | predicted (reduced) | rel. error (Exudyn) | diverged |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        md.append(
            f"| {r['omega_over_pi']}pi | {r['kp']:.4f} | {r['kd']:.4f} | {r['gains_source']} | "
            f"{r['measured_ratio_per_period']:.4f} | {r['predicted_multiplier_exudyn']:.4f} | "
            f"{r['predicted_multiplier_reduced']:.4f} | {r['relative_error_exudyn']:.2%} | {r['diverged']} |"
        )
    return {"json": "validation.json", "markdown": "\n".join(md), "figures": [fig]}


#: Registry of the study's stages, in order.
STAGES: dict[str, Callable[[StudyConfig, StudyOptions], dict]] = {
    "table2": _stage_table2,
    "table3": _stage_table3,
    "charts": _stage_charts,
    "transients": _stage_transients,
    "exudyn": _stage_exudyn,
    "validation": _stage_validation,
}


# ----------------------------------------------------------------------------- report
def _write_report(cfg: StudyConfig, opts: StudyOptions, results: dict, elapsed: float) -> tuple[Path, Path]:
    md = [
        "# flexstab study report",
        "",
        f"Manipulator: {', '.join(f'{k} = {v:g}' for k, v in cfg.manipulator.to_dict().items())}.",
        f"Fundamental motion q_a(t) = pi/2 + pi/2 sin(Omega t); Omega = {cfg.omega / math.pi:.4g} pi rad/s for the",
        f"charts, target rho_d = {cfg.target:g}. Mode: {'quick' if opts.quick else 'full'}; wall time {elapsed:.1f} s.",
        "Every number below comes from the JSON file named under its section (same folder).",
        "",
    ]
    for name, r in results.items():
        md.append(f"## {name}")
        md.append("")
        if "error" in r:
            md.append(f"**Stage failed:** `{r['error']}`")
            md.append("")
            continue
        md.append(f"Data: `{r['json']}` ({r['elapsed']:.1f} s)")
        md.append("")
        body = r["markdown"].strip().splitlines()
        if body and body[0].startswith("# "):
            body = body[2:]  # the stage's own title duplicates the section heading
        md.extend(body)
        md.append("")
        for f in r.get("figures", []):
            md.append(f"![{f}]({f})")
            md.append("")
    text = "\n".join(md) + "\n"
    md_path = opts.out / "report.md"
    md_path.write_text(text)
    html_path = opts.out / "report.html"
    html_path.write_text(_markdown_to_html(text))
    return md_path, html_path


def _markdown_to_html(text: str) -> str:
    """A small converter for the report's subset of Markdown (headings, tables, images, paragraphs)."""
    out = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>flexstab study report</title>",
           "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
           "td,th{border:1px solid #999;padding:2px 6px;font-size:90%}img{max-width:100%}</style></head><body>"]
    lines = text.splitlines()
    i = 0
    para: list[str] = []

    def flush():
        if para:
            out.append("<p>" + html.escape(" ".join(para)) + "</p>")
            para.clear()

    while i < len(lines):
        line = lines[i]
        if line.startswith("#"):
            flush()
            level = len(line) - len(line.lstrip("#"))
            out.append(f"<h{level}>{html.escape(line[level:].strip())}</h{level}>")
        elif line.startswith("!["):
            flush()
            src = line[line.index("(") + 1 : line.rindex(")")]
            out.append(f"<p><img src='{html.escape(src)}' alt='{html.escape(src)}'></p>")
        elif line.startswith("|"):
            flush()
            rows = []
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(lines[i])
                i += 1
            out.append("<table>")
            for j, row in enumerate(rows):
                if j == 1 and set(row.replace("|", "").strip()) <= set("-: "):
                    continue
                cells = [c.strip() for c in row.strip().strip("|").split("|")]
                tag = "th" if j == 0 else "td"
                out.append("<tr>" + "".join(f"<{tag}>{html.escape(c)}</{tag}>" for c in cells) + "</tr>")
            out.append("</table>")
            continue
        elif not line.strip():
            flush()
        else:
            para.append(line)
        i += 1
    flush()
    out.append("</body></html>")
    return "\n".join(out)


def run_study(cfg: StudyConfig = StudyConfig(), opts: StudyOptions = StudyOptions()) -> StudyResult:
    """Run the study's stages and write ``report.md`` / ``report.html`` to ``opts.out``.

    Raises
    ------
    ValueError
        If the output folder cannot be created or an unknown stage is named.
    """
    t0 = time.perf_counter()
    stages = opts.stages or tuple(STAGES)
    unknown = [s for s in stages if s not in STAGES]
    if unknown:
        raise ValueError(f"unknown stage(s) {', '.join(unknown)}; available: {', '.join(STAGES)}")
    try:
        opts.out.mkdir(parents=True, exist_ok=True)
        probe = opts.out / ".write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise ValueError(f"output folder {str(opts.out)!r} cannot be written: {exc.strerror}") from None
    results: dict[str, dict] = {}
    bar = None
    if opts.progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(stages), desc="study", unit="stage")
    for name in stages:
        if bar is not None:
            bar.set_postfix_str(name)
        ts = time.perf_counter()
        try:
            r = STAGES[name](cfg, opts)
        except Exception as exc:  # a failed stage is reported, the study goes on
            logger.error("stage %s failed: %s", name, exc)
            logger.debug("%s", traceback.format_exc())
            r = {"error": f"{type(exc).__name__}: {exc}"}
        r["elapsed"] = time.perf_counter() - ts
        results[name] = r
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    elapsed = time.perf_counter() - t0
    md, ht = _write_report(cfg, opts, results, elapsed)
    summary = {k: {kk: vv for kk, vv in v.items() if kk != "markdown"} for k, v in results.items()}
    (opts.out / "study.json").write_text(json.dumps({"elapsed": elapsed, "quick": opts.quick, "stages": summary},
                                                    indent=2, default=str))
    return StudyResult(opts.out, md, ht, results, elapsed)
