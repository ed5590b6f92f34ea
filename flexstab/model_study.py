"""The study of a user's model file, as one command (``flexstab study --model PATH.py``).

Stages, in this process (the model is loaded from a file), each writing its JSON
beside the report:

1. ``floquet``  -- periodic orbit (collocation residual and the one-period Exudyn
   shooting check), constraint-correct linearisation and the uncontrolled
   multipliers with their mode labels (:func:`linearize.analysis.analyze`);
2. ``tuning``   -- Taguchi tuning of the ``2 N`` gains of the ``N`` drives to
   ``rho_d`` on the plant of :func:`flexstab.plants.plant_for` (the rule of
   ``tune --model`` and ``chart --model``: Hill's method for the built-in
   two-link, else the frozen-modal product, with
   :func:`flexstab.tuning.tune_model_plant`'s step-doubling check at the
   tuned gains) and the labelled multipliers at the tuned gains from a separate
   evaluation (:func:`~linearize.analysis.analyze` with twice the loop's steps,
   at least its default and at most 4096 -- a Hill loop: its default -- with its
   own step-doubling estimate);
3. ``charts``   -- the gain chart of the first drive (the others at their tuned
   gains) and the Omega chart (:func:`flexstab.chart_runs.model_charts`);
4. ``validation`` -- multipliers measured from nonlinear Exudyn runs of the
   tuned closed loop (:func:`validation.multipliers.validate_model_multipliers`).

A model without drives has no gains: stages 2 and the gain chart are skipped
and the validation runs uncontrolled.  If the tuning stage fails, the charts
and the validation run at zero gains and say so (a note in the section and in
``study.json``: "tuning failed: validated at zero gains").  A failed stage is reported (its error
in the report, exit code 1) and the study goes on; so is a stage that computed but
whose check failed (status ``"check failed"``, exit code 1): a tuning that did not
converge, a separate evaluation at the tuned gains further than the tolerance plus
its own estimate from ``rho_d``, a validation whose measured multipliers do not
confirm the prediction.

Resuming: the stages run on the study's stage runner (:mod:`flexstab.stages`), each writing its record
``<stage>.stage.json`` with the hash of its inputs (the model file's bytes, its build options, Omega,
the samples and the packages' source; the tuning and the charts also the target, the ranges and the
quick mode; the charts and the validation also the gains they run at).  A rerun with the same inputs
reuses the finished stages (the report and ``study.json`` say which: status ``"reused"``); a changed
input recomputes the stages it reaches.  ``manifest.json`` says how the last run ended.

``quick``: coarser charts (5 x 5 gains, 3 Omegas), 300 Floquet evaluations per
tuning pass (else 600); the orbit, linearisation, tuning tolerance, Floquet checks
and the validation's three step levels are the same.
"""
from __future__ import annotations

import csv
import json
import logging
import math
import resource
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

from flexstab.report import figure, table, text, to_html, to_markdown
from flexstab.stages import STATUS_CHECK_FAILED, StudyResult  # noqa: F401  (STATUS_CHECK_FAILED: exported)

__all__ = ["ModelStudyOptions", "run_model_study", "tuning_check_failures", "STATUS_CHECK_FAILED",
           "TUNING_FAILED_VALIDATION", "QUICK_EVALUATIONS", "EVALUATIONS"]

logger = logging.getLogger(__name__)

#: Taguchi evaluations per tuning pass of a ``quick`` study and of a full one.
QUICK_EVALUATIONS = 300
EVALUATIONS = 600
#: Notes of the validation and chart stages when the tuning stage failed (no tuned gains).
TUNING_FAILED_VALIDATION = "tuning failed: validated at zero gains"
TUNING_FAILED_CHARTS = "tuning failed: the other drives at zero gains, the Omega chart's controlled curve at zero gains"



@dataclass(frozen=True)
class ModelStudyOptions:
    """Options of :func:`run_model_study`.

    Attributes
    ----------
    out : Path
        Output folder (created).
    omega : float
        Frequency of the model's periodic motion (rad/s).
    target : float
        ``rho_d`` of the tuning.
    kp_range, kd_range : (float, float)
        Initial ranges of every drive's kp and kd.
    samples : int
        Collocation samples per period.
    elements : int, optional
        ANCF elements of a built-in model (``None``: its default; the single link: the configuration's).
    quick : bool
        Coarser charts and validation (see the module docstring).
    log : callable, optional
        Called with one line when a stage starts or ends (the CLI: on a non-terminal stderr).
    progress : bool or callable
        Progress of the tuning and the charts: tqdm bars, or a bar factory (:mod:`flexstab.progress`; the
        CLI: tqdm on a terminal stderr, one line per step otherwise).
    resume : bool
        Reuse finished stages whose inputs are unchanged (default True).
    """

    out: Path = Path("results")
    omega: float = 2 * math.pi
    target: float = 0.3
    kp_range: tuple = (0.0, 60.0)
    kd_range: tuple = (0.0, 40.0)
    samples: int = 32
    elements: Optional[int] = None
    quick: bool = False
    log: Optional[Callable[[str], None]] = None
    progress: Any = False
    resume: bool = True


def _cpu() -> float:
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def _c(z) -> str:
    return f"{z.real:+.6f}{z.imag:+.6f}i"


def _gains_text(names, kp, kd) -> str:
    return "; ".join(f"{n}: kp = {a:.4g}, kd = {b:.4g}" for n, a, b in zip(names, kp, kd))


def _multiplier_blocks(res, what: str, tail: str = "") -> list:
    """A paragraph (``what``, the step count, estimate, spectral radius, dominant |rho|) and the
    table of the 12 largest labelled multipliers of ``res`` (a ModelFloquetResult)."""
    f = res.floquet
    rows = [[i + 1, _c(mu), f"{abs(mu):.6f}", m.mode, m.group, "yes" if m.undamped else "no"]
            for i, (mu, m) in enumerate(zip(f.multipliers, res.modes))]
    return [text(f"{what} ({f.n_steps} `{f.method}` steps, step-doubling estimate {f.error_estimate:.1e}): dominant "
                 f"labelled multiplier |ρ| = {abs(res.dominant_multiplier):.6f}{tail}; spectral radius "
                 f"{f.spectral_radius:.6f}. All multipliers: `multipliers.csv`."),
            table(["#", "ρ", "|ρ|", "mode", "Exudyn item", "undamped"], rows[:12])]


def _write_csv(path: Path, results: dict) -> None:
    """One row per multiplier of every labelled Floquet result in ``results`` (name -> ModelFloquetResult)."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["case", "index", "re", "im", "modulus", "mode", "group", "undamped"])
        for case, res in results.items():
            for i, (mu, m) in enumerate(zip(res.floquet.multipliers, res.modes)):
                w.writerow([case, i + 1, repr(float(mu.real)), repr(float(mu.imag)), repr(float(abs(mu))),
                            m.mode, m.group, bool(m.undamped)])


def run_model_study(model: str, cfg: Any, opts: ModelStudyOptions) -> StudyResult:
    """Run the model-file study (see the module docstring) and write ``report.md`` / ``report.html``.

    One study per output folder: the folder is locked while it runs (:func:`flexstab.study.folder_lock`).

    Parameters
    ----------
    model : str
        A model file ``PATH.py`` or a built-in model name.
    cfg : flexstab.config.StudyConfig
        Decides the built-in single link's parameters and mesh (:func:`flexstab.options.resolve_model_definition`).
    opts : ModelStudyOptions

    Raises
    ------
    ValueError
        Bad model file or options (before any stage runs).
    """
    from flexstab.options import ensure_out_dir, resolve_model_definition

    t0, c0 = time.perf_counter(), _cpu()
    damping = getattr(cfg, "damping", None)  # --damping / [study] damping: the beams' structural damping
    definition, options = resolve_model_definition(model, cfg, opts.elements,
                                                   **(damping.build_options() if damping is not None else {}))
    out = ensure_out_dir(opts.out)
    from flexstab.stages import folder_lock

    with folder_lock(out):
        return _run_model_study(model, cfg, opts, definition, options, out, t0, c0)


def _run_model_study(model: str, cfg: Any, opts: ModelStudyOptions, definition: Any, options: dict, out: Path,
                     t0: float, c0: float) -> StudyResult:
    """:func:`run_model_study` in its locked output folder."""
    from flexstab import provenance as pv
    from flexstab.tuning import factor_ranges, tune_model_plant
    from flexstab.options import gain_pairs
    from flexstab.plants import MAX_TUNING_STEPS, plant_choice_for
    from flexstab.stages import Stage, StageOutput, StageRunner, stage_section
    from flexstab.study import validation_blocks
    from linearize.analysis import DEFAULT_PROPAGATOR_STEPS, analyze
    from linearize.hill_plant import HillModelPlant
    from mbs_models.model_file import ModelFileError
    from taguchi.tuning import TuningConfig

    for f in ("report.md", "report.html", "study.json"):  # never leave a report of another run beside this one
        (out / f).unlink(missing_ok=True)
    TuningConfig(target=opts.target, kp_range=opts.kp_range, kd_range=opts.kd_range)  # checks before the orbit
    omega = float(opts.omega)
    say = opts.log or (lambda line: None)
    sections: list = []
    state: dict = {}

    checks: list = []  # the running stage's failed checks (one line each)
    stage_notes: list = []  # the running stage's notes for the section and study.json (one line each)

    # what decides each stage's numbers (its inputs hash): the model (its file's bytes), its build options,
    # Omega, the collocation samples and the packages' source; the tuning and charts also the target, ranges
    # and quick mode; the charts and the validation also the gains they run at (known when they start)
    code = pv.code_hash()
    base_inputs = {"model": model, "definition": definition.name,
                   "source": pv.file_sha(Path(definition.source)) if definition.source else None,
                   "options": repr(sorted(options.items(), key=lambda kv: kv[0])), "omega": omega,
                   "samples": opts.samples, "code": code}
    tuning_inputs = {"target": opts.target, "kp_range": list(opts.kp_range), "kd_range": list(opts.kd_range),
                     "quick": opts.quick}
    runner = StageRunner(out, {"model": model, "definition": definition.name, "source": definition.source,
                               "omega": omega, "quick": opts.quick, "code_hash": code},
                         order=("floquet", "tuning", "charts", "validation"), resume=opts.resume, log=opts.log,
                         stamp=False, reraise=(ModelFileError,), one_line_errors=True)

    def stage(name: str, title: str, fn: Callable[[], list], files: Callable[[], tuple] = tuple,
              **inputs: Any) -> Any:
        """Run (or reuse) stage ``name``; append its section.  ``fn()`` returns the section's blocks."""

        def call() -> StageOutput:
            checks.clear()
            stage_notes.clear()
            caught: list = []
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    blocks = fn()
            finally:
                # warnings of the computation (RuntimeWarning, e.g. a Floquet step-doubling estimate above 1e-4)
                # go into the report; any other category (a library's deprecation, a UserWarning, ...) is
                # passed on to the caller's filters, also when the stage fails
                for w in caught:
                    if not issubclass(w.category, RuntimeWarning):
                        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
            notes = sorted({" ".join(str(w.message).split()) for w in caught if issubclass(w.category, RuntimeWarning)})
            blocks = blocks + [text(f"**Warning:** {n}") for n in notes]
            for n in notes:
                say(f"study: {name}: warning: {n}")
            return StageOutput(json=f"{name}.json", blocks=blocks, files=tuple(files()),
                               check_failures=tuple(checks), notes=tuple(stage_notes))

        run = runner.run_stage(Stage(name, call, {"stage": name, **base_inputs, **inputs}, title))
        if run.ok:
            sections.append((run.record.get("title") or title, stage_section(run.record, reused=run.reused)))
        else:
            sections.append((title, [text(f"**Stage failed:** `{run.error}`")]))
        return run

    def uncontrolled() -> Any:
        """The uncontrolled analysis (orbit, linearisation, multipliers): computed once, also when the
        floquet stage was reused and a later stage needs its orbit."""
        if "uncontrolled" not in state:
            state["uncontrolled"] = analyze(definition, omega, samples=opts.samples, **options)
        return state["uncontrolled"]

    def floquet_stage() -> list:
        res = uncontrolled()
        doc = res.summary()
        doc.update(omega=omega, floquet=res.floquet.to_dict())
        (out / "floquet.json").write_text(json.dumps(_ready(doc), indent=2))
        _write_csv(out / "multipliers.csv", {"uncontrolled": res})
        o = res.orbit
        return [
            text(f"Model `{definition.name}`" + (f" (`{definition.source}`)" if definition.source else "")
                 + f"; drives: {', '.join(res.drives) or 'none'}; {o.size} Exudyn coordinates, "
                 f"{res.linearization.size} independent. Periodic orbit by trigonometric collocation "
                 f"({o.samples} samples): relative residual {o.residual:.1e} (tolerance {o.tolerance:.0e}); one "
                 f"period in Exudyn from its state returns with a relative defect {o.shooting_residual:.1e}."),
            *_multiplier_blocks(res, "Uncontrolled multipliers, all gains 0"),
        ]

    def tuning_stage() -> list:
        base = uncontrolled()
        nd = len(base.drives)
        names, ranges = factor_ranges(nd, opts.kp_range, opts.kd_range, None)
        tcfg = TuningConfig(target=opts.target, ranges=ranges, names=names,
                            max_evaluations=QUICK_EVALUATIONS if opts.quick else EVALUATIONS)
        # the plant rule of tune --model and chart --model (Hill for the built-in two-link)
        sel = plant_choice_for(definition, base.orbit, base.linearization, tcfg)
        plant = sel.plant
        res, plant, passes = tune_model_plant(plant, tcfg, progress=opts.progress)
        hill = isinstance(plant, HillModelPlant)
        kp, kd = (list(g) if isinstance(g, (list, tuple)) else [g] for g in gain_pairs(res.gains, nd))
        state["gains"] = (kp, kd)
        # beside the loop's evaluations: a frozen-modal product (twice a time-stepping loop's propagator steps,
        # at least analyze's default, at most the tuning's cap, which bounds the work arrays; a Hill loop: analyze's
        # default), with analyze's own step-doubling estimate
        n_check = DEFAULT_PROPAGATOR_STEPS if hill else max(DEFAULT_PROPAGATOR_STEPS,
                                                            min(2 * plant.n_steps, MAX_TUNING_STEPS))
        check = analyze(definition, omega, kp=kp, kd=kd, orbit=base.orbit, n_steps=n_check, **options)
        state["tuned"] = check
        _write_csv(out / "multipliers.csv", {"uncontrolled": base, "tuned": check})
        doc = {"drives": list(base.drives), "target": opts.target, "tolerance": tcfg.effective_tolerance,
               "kp": kp, "kd": kd, "tuning": res.to_dict(), "propagator_passes": passes,
               "response_method": "hill" if hill else "magnus2",
               "harmonics": plant.harmonics if hill else None,
               "harmonics_converged": sel.harmonics.converged if sel.harmonics is not None else None,
               "harmonics_error_estimate": sel.harmonics.error_estimate if sel.harmonics is not None else None,
               # the step choice at the range centre (null for Hill): whether MAX_TUNING_STEPS stopped it short
               "propagator_choice": sel.steps.to_dict() if sel.steps is not None else None,
               "check": {"dominant_modulus": abs(check.dominant_multiplier), "n_steps": check.floquet.n_steps,
                         "error_estimate": check.floquet.error_estimate, "floquet": check.floquet.to_dict(),
                         "modes": [m.to_dict() for m in check.modes]}}
        checks.extend(tuning_check_failures(res.status, res.message, abs(check.dominant_multiplier),
                                            _absolute_estimate(check), opts.target, tcfg.effective_tolerance))
        doc["check"]["failures"] = list(checks)
        # the whole closed loop at the tuned gains (stability.verdict), beside the tuned response
        from flexstab.plants import MODEL_RESPONSE_MODES, response_note

        whole = check.verdict.to_dict()
        doc.update({"tuned_response": float(res.spectral_radius), "tuned_response_modes": MODEL_RESPONSE_MODES,
                    "spectral_radius": whole["spectral_radius"], "spectral_radius_mode": whole["spectral_radius_mode"],
                    "spectral_radius_frequency_hz": whole["spectral_radius_frequency_hz"],
                    "spectral_radius_error_estimate": (whole["spectral_radius_error"] / whole["spectral_radius"]
                                                       if whole["spectral_radius"] else None),
                    "verdict": whole["verdict"], "verdict_detail": whole,
                    "response_note": response_note(float(res.spectral_radius), MODEL_RESPONSE_MODES, whole)})
        (out / "tuning.json").write_text(json.dumps(_ready(doc), indent=2))
        if hill:
            how = (f"{res.status} after {res.evaluations} evaluations by Hill's method ({plant.harmonics} harmonics, "
                   f"chosen at the centre of the ranges; response {res.spectral_radius:.6f})")
        else:
            last = passes[-1]
            how = (f"{res.status} after {sum(p['evaluations'] for p in passes)} Floquet evaluations in "
                   f"{len(passes)} pass(es) with {last['propagator_steps']} `magnus2` steps (response "
                   f"{last['spectral_radius']:.6f}; with twice the steps {last['check_2n']:.6f})")
        return [
            text(f"Iterative Taguchi ({tcfg.orthogonal_array().name}, {len(names)} factors "
                 f"{', '.join(names)}) to the dominant labelled multiplier |ρ| = ρ_d = {opts.target:g} "
                 f"(tolerance {tcfg.effective_tolerance:.1e}), initial ranges kp ∈ [{opts.kp_range[0]:g}, "
                 f"{opts.kp_range[1]:g}], kd ∈ [{opts.kd_range[0]:g}, {opts.kd_range[1]:g}] for every drive: "
                 f"{how}."),
            table(["drive", "kp (N·m/rad)", "kd (N·m·s/rad)"],
                  [[n, f"{a:.5g}", f"{b:.5g}"] for n, a, b in zip(base.drives, kp, kd)]),
            text(f"Whole closed loop at the tuned gains: {whole['message']}."
                 + (f" In words: {doc['response_note']}." if doc["response_note"] else "")),
            *_multiplier_blocks(check, "Check at the tuned gains, a separate evaluation",
                                f" (ρ_d = {opts.target:g})"),
        ]

    def charts_stage() -> list:
        from flexstab import chart_runs

        kp, kd = gains()
        untuned = bool(drives) and not kp
        if untuned:
            stage_notes.append(TUNING_FAILED_CHARTS)
        chart = chart_runs.ChartOptions(
            model=model, out=out, omega=omega, kp_range=tuple(opts.kp_range), kd_range=tuple(opts.kd_range),
            grid=5 if opts.quick else 11, target=opts.target, omega_points=3 if opts.quick else 9,
            kp=tuple(kp) or None, kd=tuple(kd) or None, no_taguchi=True, elements=opts.elements,
            samples=opts.samples)
        s = chart_runs.model_charts(chart, cfg, progress=opts.progress)
        chart_files.append(Path(s["json"]).name)
        (out / "charts.json").write_text(json.dumps(_ready(s), indent=2))
        figs = [Path(f).name for f in s["figures"]]
        o = s["omega_chart"]
        blocks = []
        if s["gain_chart"] is not None:
            g = s["gain_chart"]
            others = [d for d in drives if d != s["charted_drive"]]
            blocks.append(figure(figs[0], f"Dominant |ρ| over the (kp, kd) plane of drive {s['charted_drive']} "
                                          f"({len(g['kp'])} × {len(g['kd'])} grid)"
                                 + (f", {', '.join(others)} at "
                                    + ("zero gains (tuning failed)" if untuned else "the tuned gains")
                                    if others else "")
                                 + f"; the ρ_d = {opts.target:g} contour dashed."))
        blocks.append(figure(figs[-1], f"Dominant |ρ| against Ω ({len(o['omega'])} values from "
                                       f"{o['omega'][0]:.4g} to {o['omega'][-1]:.4g} rad/s, each orbit continued "
                                       "from the previous), uncontrolled and at "
                                       + ("zero gains (tuning failed: both curves coincide)." if untuned
                                          else "the tuned gains.")))
        how = (f"Hill's method ({s['harmonics']} harmonics) per point; H vs H/2 estimate" if s.get("harmonics")
               else f"{s['propagator_steps']} `magnus2` steps per point; step-doubling estimate")
        blocks.insert(0, text(f"{how} at Ω = {omega:.4g} rad/s and the tuned gains "
                              f"{s['propagator_error_estimate']:.1e} (the tuning's response rule)."))
        return blocks

    def validation_stage() -> list:
        from validation.multipliers import MultiplierCheckConfig, validate_model_multipliers
        from validation.plots import plot_multiplier_plane

        kp, kd = gains()
        untuned = bool(drives) and not kp
        if untuned:  # the tuning stage failed: there are no tuned gains to validate
            stage_notes.append(TUNING_FAILED_VALIDATION)
        # the validation path's own step rule (suggested_step: unresolved damped modes keep spurious
        # multipliers below 1e-2) and amplitude; three step levels in every mode, so the step error bar
        # rests on an observed convergence order (two levels cannot show one)
        check = MultiplierCheckConfig(step=None, amplitude=None, refinements=2)
        v = validate_model_multipliers(definition, omega, kp=kp or 0.0, kd=kd or 0.0, config=check, **options)
        d = v.to_dict()
        d["gains_source"] = TUNING_FAILED_VALIDATION if untuned else ("tuned" if kp else "no drives")
        from flexstab.checks import validation_failures

        checks.extend(f"validation: {line}" for line in validation_failures(d))
        (out / "validation.json").write_text(json.dumps(_ready(d), indent=2, default=float))
        fig = "validation_multipliers.png"
        plot_multiplier_plane([v], out / fig, titles=[f"{definition.name}, Ω = {omega:.4g} rad/s"],
                              suptitle="Multipliers measured from nonlinear Exudyn runs vs predicted")
        if untuned:
            words = f"{TUNING_FAILED_VALIDATION}, " + _gains_text(drives, [0.0] * len(drives), [0.0] * len(drives))
        else:
            words = _gains_text(drives, kp, kd) if kp else "no drives (uncontrolled)"
        # the steps the measurement used (d["steps"]: chosen by its own rule, check.steps is empty for step=None)
        return validation_blocks(d, f"Model `{definition.name}` under feed-forward + PD ({words}).",
                                 d.get("steps") or check.steps, fig)

    def gains() -> tuple[list, list]:
        """The tuned gains (this run's, else the reused tuning's ``tuning.json``); none if the tuning failed."""
        if "gains" in state:
            return state["gains"]
        if tuned is not None and tuned.ok:
            doc = json.loads((out / "tuning.json").read_text())
            return list(doc["kp"]), list(doc["kd"])
        return [], []

    chart_files: list = []
    drives: list = []
    tuned = None
    try:
        fl = stage("floquet", f"Periodic orbit and uncontrolled multipliers at Ω = {omega:.6g} rad/s", floquet_stage,
                   # the uncontrolled multipliers are final when no tuning rewrites them
                   files=lambda: () if state["uncontrolled"].drives else ("multipliers.csv",))
        if fl.ok:
            drives = (list(state["uncontrolled"].drives) if "uncontrolled" in state
                      else list(json.loads((out / "floquet.json").read_text())["drives"]))
        if fl.ok and drives:
            tuned = stage("tuning", f"PD gains by Taguchi tuning (ρ_d = {opts.target:g})", tuning_stage,
                          files=lambda: ("multipliers.csv",), **tuning_inputs)
        elif fl.ok:
            sections.append(("PD gains by Taguchi tuning", [text("The model has no drives: no gains to tune.")]))
        if fl.ok:
            kp, kd = gains()
            stage("charts", "Stability charts", charts_stage, files=lambda: tuple(chart_files), **tuning_inputs,
                  elements=opts.elements, gains=[kp, kd])
            stage("validation", "Nonlinear validation", validation_stage, gains=[kp, kd])
    except BaseException as exc:
        runner.stop(exc, time.perf_counter() - t0)
        raise
    elapsed, cpu = time.perf_counter() - t0, _cpu() - c0
    runner.finish(elapsed=elapsed, cpu=cpu)
    reused = [n for n, r in runner.runs.items() if r.reused]
    preamble = [
        text(f"Model `{definition.name}`" + (f" from `{definition.source}`" if definition.source else "")
             + f" at Ω = {omega:.6g} rad/s (T = {2 * math.pi / omega:.6g} s); mode: {'quick' if opts.quick else 'full'}"
             + "; every number below comes from the JSON file named under its section (same folder)."),
        text(f"Wall time {elapsed:.1f} s, CPU {cpu:.1f} s."
             + (f" Reused from an earlier run with the same inputs: {', '.join(reused)}." if reused else "")),
    ]
    md, html_path = out / "report.md", out / "report.html"
    md.write_text(to_markdown(f"flexstab study: model {definition.name}", preamble, sections))
    html_path.write_text(to_html(f"flexstab study: model {definition.name}", preamble, sections))
    (out / "study.json").write_text(json.dumps({"model": model, "omega": omega, "quick": opts.quick,
                                                "elapsed": elapsed, "cpu": cpu, "stages": runner.summaries()}, indent=2))
    return StudyResult(out, md, html_path, runner.summaries(), elapsed)


def _absolute_estimate(res) -> float:
    """Absolute error estimate of ``|dominant multiplier|`` of a ModelFloquetResult (its relative
    estimate times the modulus); 0 when no finite estimate exists (the check is then the strictest)."""
    dom = abs(res.dominant_multiplier)
    for est in (res.dominant_error_estimate, res.floquet.error_estimate):
        if est is not None and math.isfinite(float(est)):
            return float(est) * dom
    return 0.0


def tuning_check_failures(status: str, message: str, checked: float, estimate: float, target: float,
                          tolerance: float) -> list:
    """The failed checks of a tuning stage, one line each (empty: every check passed).

    Parameters
    ----------
    status, message : str
        The tuning's status (``"converged"`` passes) and its message.
    checked, estimate : float
        ``|rho|`` of the separate evaluation at the tuned gains and its absolute error estimate.
    target, tolerance : float
        ``rho_d`` and the tuning tolerance: the check passes iff ``|checked - rho_d| <= tolerance + estimate``
        (the tuned response is within ``tolerance`` of ``rho_d``; the separate evaluation is within
        ``estimate`` of the exact value).
    """
    out = []
    if status != "converged":
        out.append(f"tuning not converged ({status}: {' '.join(str(message).split())})")
    if not (abs(checked - target) <= tolerance + estimate):
        out.append(f"the separate evaluation at the tuned gains gives |ρ| = {checked:.6g}, |ρ - ρ_d| = "
                   f"{abs(checked - target):.2e} > tolerance {tolerance:.1e} + estimate {estimate:.1e}")
    return out


def _ready(obj):
    from stability.serialization import json_ready

    return json_ready(obj)
