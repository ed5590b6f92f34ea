"""The whole study on one manipulator, as one command (``flexstab study``).

Stages, each writing its JSON beside the report so that every number in the
report can be traced to a file:

1. ``table2``  -- Floquet multipliers of the uncontrolled reduced model (paper Table 2);
2. ``table3``  -- Taguchi tuning of the reduced model to rho_d (paper Table 3);
3. ``charts``  -- max|rho| over the gain plane (with the Taguchi path) and against Omega;
4. ``transients`` -- linear transient responses (paper Figs. 2-9);
5. ``exudyn``  -- the Exudyn ANCF model (the built-in model file ``single-link``): periodic
   orbit, linearisation, Floquet at the reference gains, Taguchi tuning on it (``quick``:
   at most 4 elements, 16 collocation samples, the tuning loop at half the
   propagator steps with the tuned gains re-evaluated at the full count);
6. ``validation`` -- nonlinear Exudyn simulations of the tuned closed loop
   against the predicted multipliers;
7. ``two_link`` -- the built-in two-link flexible arm (:mod:`flexstab.two_link_report`):
   orbit, Floquet uncontrolled, four-gain Taguchi tuning with an independent check of the
   tuned value, figures (full study only; ``--quick`` leaves it out unless named);
8. ``sensitivity`` -- the verdict of the whole closed loop (:mod:`stability.verdict`) at the
   reference gains for 2, 4, 8 ANCF elements (``quick``: 2, 4), without and with structural damping.

The report opens with the verdict block (:mod:`flexstab.verdict_report`): uncontrolled, tuned and
nonlinear check, in words and numbers (also the ``verdict`` key of ``study.json``).

Which Omega
-----------
Every stage computes at the *study Omega* (``[study] omega``, default 2pi).
For the paper's manipulator (every Table 1 value unchanged), the stages that
reproduce printed results -- Table 2, Table 3 and Figs. 2-9 -- also compute
at the paper's Omegas 2pi, 4pi, 6pi, 8pi (``quick``: only the case at the
study Omega, or 2pi if the study Omega is none of them) and compare with the
printed numbers.  For any other manipulator nothing is compared with the
paper: the printed values describe the paper's link only.

Reference gains (Exudyn stage, controlled transients): the printed Table 3
gains for the paper's manipulator at a paper Omega, otherwise the gains that
Taguchi tunes on the reduced model at the study Omega.

Runs and resuming
-----------------
``manifest.json`` names the configuration (and its hash) that the folder's
report describes.  Each finished stage writes ``<stage>.stage.json``: the
hash of its inputs (configuration, quick mode, source code of the packages),
the report blocks of its section and the SHA-256 of every file it wrote; its
data JSON carries the same hashes under ``"study"``.  A rerun with unchanged
inputs reuses the finished stages (the report says which), and the report is
rendered only from stages whose records and files match the manifest, so it
never mixes runs (:func:`render_report` raises otherwise).  The records, hashes
and the manifest are :mod:`flexstab.provenance`'s; the stages run on
:class:`flexstab.stages.StageRunner`, as those of a model file's study do
(:mod:`flexstab.model_study`).

Stages 5-6 need the Exudyn layer; if a stage fails, the report says so and
names the error instead of the study crashing.

Processes
---------
With ``jobs >= 2`` (default 2) each chain of :data:`EXUDYN_CHAINS` -- the Exudyn
chain (``exudyn`` then ``validation``, which reads the gains ``exudyn`` tuned)
and the two-link section -- runs in a process of its own, forked once from the
main thread with matplotlib, pydoe and the compiled Floquet kernel already
loaded (only those processes import Exudyn), while this process runs the other
stages in order; the transient cases and the chart points run in process pools
of their own.  (The two-link section has its own process because in the Exudyn
chain it made that chain the longest: ``--quick`` 13.4 s CPU against 8.8 s here.)
Every record is written by this process as its stage finishes, with the stage's
wall time and CPU time (``time.process_time`` of the process that ran it plus
``RUSAGE_CHILDREN`` of its pools).  A new stage that runs Exudyn belongs in a
chain of :data:`EXUDYN_CHAINS`.
"""
from __future__ import annotations

import functools
import json
import logging
import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Optional, Sequence

from flexstab import provenance as pv
from flexstab.config import StudyConfig
from flexstab.report import figure, omega_text, pi_multiple, relative, table, text, to_html, to_markdown
from flexstab.stages import LOCK_FILE, Stage, StageOutput, StageRunner, StudyResult, cpu_now, folder_lock, stage_section

__all__ = ["StudyOptions", "StudyResult", "run_study", "render_report", "STAGES", "STAGE_TITLES", "config_hash",
           "validation_blocks", "folder_lock", "LOCK_FILE"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StudyOptions:
    """Options of :func:`run_study`.

    Attributes
    ----------
    out : Path
        Output folder (created); one study configuration per folder at a time.
    quick : bool
        Fewer cases and coarser grids (the ``--quick`` mode).
    stages : tuple of str
        Which stages to run (default all of :data:`STAGES`).
    progress : bool
        Show tqdm progress bars (for a terminal).
    scheduler : str, optional
        Dask scheduler address for the chart sweep.
    log : callable, optional
        Called with one line of text when a stage starts, finishes, fails or is reused
        (the CLI writes these lines to stderr when stderr is not a terminal).
    resume : bool
        Reuse finished stages whose inputs are unchanged (default True).
    jobs : int
        Processes (default 2): with 2 or more, each chain of :data:`EXUDYN_CHAINS` runs in a
        process of its own beside the other stages; 1 runs every stage in this process.
    """

    out: Path = Path("results")
    quick: bool = False
    stages: tuple[str, ...] = ()
    progress: bool = True
    scheduler: Optional[str] = None
    log: Optional[Callable[[str], None]] = None
    resume: bool = True
    jobs: int = 2


# ----------------------------------------------------------------------------- inputs and hashes
def config_dict(cfg: StudyConfig) -> dict:
    """The configuration as a JSON-ready dict (what the manifest records)."""
    return {
        "manipulator": cfg.manipulator.to_dict(),
        "omega": cfg.omega,
        "target": cfg.target,
        "kp_range": list(cfg.kp_range),
        "kd_range": list(cfg.kd_range),
        "elements": cfg.elements,
        # structural damping only when set (the hash of an undamped study's configuration is unchanged)
        **({"damping": cfg.damping.to_dict()} if getattr(cfg.damping, "given", False) else {}),
    }


def config_hash(cfg: StudyConfig) -> str:
    """Short SHA-256 of the configuration (manipulator and study settings)."""
    return pv.short_hash(pv.canonical(config_dict(cfg)), 12)


# ----------------------------------------------------------------------------- which cases
def _is_paper(cfg: StudyConfig) -> bool:
    from flexstab.paper_tables import is_paper_manipulator

    return is_paper_manipulator(cfg.manipulator)


def _repro_omegas(cfg: StudyConfig, quick: bool) -> tuple[int, ...]:
    """Paper Omegas (units of pi) reproduced for the paper's manipulator (see module docstring)."""
    from flexstab.paper_tables import PAPER_OMEGAS_OVER_PI, paper_case

    if not _is_paper(cfg):
        return ()
    if not quick:
        return PAPER_OMEGAS_OVER_PI
    k = paper_case(cfg.omega)
    return (k if k is not None else 2,)


_w = omega_text  # "2π rad/s"
_pi = pi_multiple  # "2π"


def _reference_gains(cfg: StudyConfig, opts: StudyOptions) -> tuple[float, float, str]:
    """Printed Table 3 gains (paper's manipulator at a paper Omega), else Taguchi on the reduced model."""
    from flexstab.paper_tables import TABLE3_PRINTED, paper_case

    k = paper_case(cfg.omega)
    if _is_paper(cfg) and k is not None:
        for kk, _, kp, kd, _ in TABLE3_PRINTED:
            if kk == k:
                return kp, kd, "paper Table 3 gains"
    rec = pv.load_record(opts.out, "table3")
    if rec is not None and rec.get("config_hash") == config_hash(cfg):
        for r in json.loads((opts.out / rec["json"]).read_text())["rows"]:
            if abs(r["omega"] - cfg.omega) <= 1e-9 * cfg.omega and abs(r["target"] - cfg.target) <= 1e-12:
                return r["kp"], r["kd"], "Taguchi on the reduced model (table3.json)"
    from mbs_models.reduced import ReducedModel
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    res = taguchi_tune(GainObjective(ReducedModel(cfg.omega, params=cfg.manipulator)),
                       TuningConfig(target=cfg.target, kp_range=cfg.kp_range, kd_range=cfg.kd_range))
    return res.kp, res.kd, "Taguchi on the reduced model"


# ----------------------------------------------------------------------------- stages
def _stage_table2(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    from flexstab.paper_tables import paper_case, table2_blocks, table2_rows

    omegas = [k * math.pi for k in (2, 4, 6, 8)] if _is_paper(cfg) else []
    if paper_case(cfg.omega) is None or not _is_paper(cfg):
        omegas.append(cfg.omega)
    rows = table2_rows(params=cfg.manipulator, omegas=omegas)
    (opts.out / "table2.json").write_text(json.dumps({"rows": rows}, indent=2))
    title = ("Floquet multipliers without control (paper Table 2)" if _is_paper(cfg)
             else f"Floquet multipliers without control at Ω = {_w(cfg.omega)}")
    return StageOutput(json="table2.json", title=title, blocks=table2_blocks(rows))


def _stage_table3(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    from flexstab.paper_tables import TABLE3_PRINTED, paper_case, table3_blocks, table3_rows

    cases = [c for c in TABLE3_PRINTED if c[0] in _repro_omegas(cfg, opts.quick)]
    k = paper_case(cfg.omega)
    if not (_is_paper(cfg) and k is not None and any(c[0] == k and c[1] == cfg.target for c in cases)):
        cases.append((cfg.omega / math.pi, cfg.target, None, None, None))
    rows = table3_rows(cases, params=cfg.manipulator, kp_range=cfg.kp_range, kd_range=cfg.kd_range)
    (opts.out / "table3.json").write_text(json.dumps({"rows": rows}, indent=2))
    title = ("PD gains by Taguchi tuning (paper Table 3)" if _is_paper(cfg)
             else f"PD gains by Taguchi tuning at Ω = {_w(cfg.omega)}")
    paper_rows = [r for r in rows if "printed_kp" in r]
    other = [r for r in rows if "printed_kp" not in r]
    blocks = table3_blocks(paper_rows) if paper_rows else []
    if other:
        if paper_rows:
            blocks.append(text(f"At the study Ω = {_w(cfg.omega)} (ρ_d = {cfg.target:g}, no printed gains):"))
        blocks += table3_blocks(other)
    return StageOutput(json="table3.json", title=title, blocks=blocks)


def _stage_charts(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    from flexstab.chart_runs import ChartOptions, make_charts

    chart = ChartOptions(model="reduced", out=opts.out, omega=cfg.omega, kp_range=tuple(cfg.kp_range),
                         kd_range=tuple(cfg.kd_range), grid=15 if opts.quick else 41, target=cfg.target,
                         omega_points=31 if opts.quick else 121, scheduler=opts.scheduler)
    s = make_charts(chart, cfg, progress=opts.progress)
    g, o = s["gain_chart"], s["omega_chart"]
    names = [Path(f).name for f in s["figures"]]
    blocks = [
        text(f"Reduced model, {len(g['kp'])} × {len(g['kd'])} gain grid, kp in [{g['kp'][0]:g}, {g['kp'][-1]:g}] "
             f"N·m/rad, kd in [{g['kd'][0]:g}, {g['kd'][-1]:g}] N·m·s/rad; {len(o['omega'])} values of Ω from "
             f"{_pi(o['omega'][0])} to {_pi(o['omega'][-1])} rad/s."),
        figure(names[0], f"max|ρ| over the (kp, kd) plane at Ω = {_w(cfg.omega)}: blue = asymptotically stable "
                         f"(|ρ| < 1), red = unstable; the |ρ| = 1 boundary, the ρ_d = {cfg.target:g} contour and the "
                         "Taguchi path (incumbent after each iteration) are drawn."),
        figure(names[1], f"max|ρ| against Ω, uncontrolled and with the tuned gains kp = {o['kp']:.4g} N·m/rad, "
                         f"kd = {o['kd']:.4g} N·m·s/rad."),
    ]
    return StageOutput(json=Path(s["json"]).name, title=f"Stability charts at Ω = {_w(cfg.omega)}",
                       blocks=blocks, files=tuple(names + [Path(s["json"]).name]))


def _stage_transients(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    from flexstab.paper_tables import paper_case
    from flexstab.transients import CASES, Case, make_transients, paper_case_pair

    cases: list = []
    repro = _repro_omegas(cfg, opts.quick)
    if repro:
        cases = [c for c in CASES if c.omega_over_pi in repro]
    k = paper_case(cfg.omega)
    if not (_is_paper(cfg) and k is not None and k in repro):
        kp, kd, source = _reference_gains(cfg, opts)
        w = cfg.omega / math.pi
        if _is_paper(cfg) and k is not None:
            cases += list(paper_case_pair(k))
        else:
            cases += [Case(None, w, gains_source="no control"), Case(None, w, kp, kd, gains_source=source)]
    from flexstab.executor import make_executor

    # the cases are independent: two processes (the figures are half the stage's time)
    with make_executor("process" if len(cases) > 1 else "serial", max_workers=2) as ex:
        doc = make_transients(opts.out, quick=opts.quick, params=cfg.manipulator, cases=cases, executor=ex)
    figs = [c["figure_file"] for c in doc["cases"]]
    rows = []
    for c in doc["cases"]:
        rows.append([f"Fig. {c['figure']}" if c["figure"] is not None else (c["gains_source"] or "given gains"),
                     f"{c['omega_over_pi']:.4g}π", f"{c.get('kp', 0):g}", f"{c.get('kd', 0):g}",
                     f"{c['spectral_radius']:.6g}", f"{c['last_ratio']:.6g}", f"k = {c['periods_measured'] - 1}",
                     relative(c["last_ratio_relative_error"])])
    blocks = [
        text("Homogeneous response (Eq. 25/33) of the linearised reduced model from x(0) = [0, 0, 0.25π, 0] "
             "(Eqs. 26/35), with the envelope ρ₁^(t/T) of the dominant multiplier. Measured growth per period "
             "‖x((k+1)T)‖/‖x(kT)‖ at the last integrated period k (it tends to |ρ₁| like |ρ₂/ρ₁|^k):"),
        table(["case", "Ω", "kp (N·m/rad)", "kd (N·m·s/rad)", "|ρ₁|", "measured ratio", "at",
               "relative difference"], rows),
    ]
    blocks += [figure(c["figure_file"], (f"Fig. {c['figure']}. " if c["figure"] is not None else "") + c["caption"])
               for c in doc["cases"]]
    paper_figs = sorted(c["figure"] for c in doc["cases"] if c["figure"] is not None)
    title = (f"Transient responses (paper Figs. {', '.join(map(str, paper_figs))})" if paper_figs
             else f"Transient responses at Ω = {_w(cfg.omega)}")
    return StageOutput(json="transients.json", title=title, blocks=blocks, files=tuple(figs + ["transients.json"]))


def _stage_exudyn(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    """Exudyn model at the study Omega: orbit, linearisation, Floquet at the reference gains; Taguchi on it."""
    import dataclasses

    from linearize.analysis import ModelPlant, analyze
    from mbs_models.reduced import ReducedModel
    from stability import floquet
    from stability.refine import pair_estimate
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    elements = min(cfg.elements, 4) if opts.quick else cfg.elements
    omega = cfg.omega
    kp_r, kd_r, source = _reference_gains(cfg, opts)
    # --quick: 16 collocation samples per period (32 in the full study; at 4 elements and 2pi the
    # dominant multipliers at the reference, zero and tuned gains agree to 1e-9 between the two)
    samples = 16 if opts.quick else 32
    damp = getattr(cfg.damping, "given", False)  # [study] damping / --damping: the beams' structural damping
    definition, options = _link_definition(cfg, elements, damped=damp)
    ef = analyze(definition, omega, kp=kp_r, kd=kd_r, samples=samples, **options)
    # tuning on the same orbit and linearisation (gains 0): the model-file plant (frozen-modal frame built at
    # each evaluation's gains, extrapolated; linearize.analysis.TUNING_PROPAGATOR_STEPS)
    plant = ModelPlant(ef.linearization.with_gains(0.0, 0.0), ef.orbit)
    uncontrolled = plant.spectral_measure(0.0, 0.0)
    tcfg = TuningConfig(target=cfg.target, kp_range=cfg.kp_range, kd_range=cfg.kd_range,
                        max_evaluations=100 if opts.quick else 300)
    # in this process (the study's second process runs beside the others): one workspace, no pool.
    # --quick: the loop runs with half the plant's propagator steps; the tuned gains are re-evaluated
    # with the full count, and tuned again with it if the step-doubling estimate (second order: the
    # error of n steps ~ 4/3 |r_n - r_2n|) exceeds a quarter of the tuning tolerance
    loop = dataclasses.replace(plant, n_steps=plant.n_steps // 2) if opts.quick else plant
    tuned = taguchi_tune(GainObjective(loop), tcfg)
    tuned_dominant = tuned.spectral_radius
    step_check = None
    if loop is not plant:
        tuned_dominant = plant.spectral_measure(tuned.kp, tuned.kd)
        step_check = pair_estimate(tuned.spectral_radius, tuned_dominant)
        if step_check > 0.25 * tcfg.effective_tolerance:
            logger.info("quick tuning: step-doubling estimate %.1e at the tuned gains; tuning again with %d steps",
                        step_check, plant.n_steps)
            tuned = taguchi_tune(GainObjective(plant), tcfg)
            tuned_dominant, loop = tuned.spectral_radius, plant
    reduced = floquet(ReducedModel(omega, kp_r, kd_r, cfg.manipulator)).spectral_radius
    # ---- verdicts of the whole closed loop (stability.verdict; the verdict block of the report reads them)
    verdicts = {"verdict_uncontrolled": _whole_loop_verdict(ef, 0.0, 0.0),
                "verdict_reference": ef.verdict.to_dict(),
                "verdict_tuned": _whole_loop_verdict(ef, tuned.kp, tuned.kd)}
    # ---- end of the verdicts
    row = {
        "omega": omega, "omega_over_pi": omega / math.pi, "elements": elements, "samples": samples,
        "target": cfg.target,
        "orbit_residual": float(ef.orbit.residual),
        # one Exudyn period from the orbit's state (computed by analyze's verify_orbit anyway)
        "orbit_shooting_residual": float(ef.orbit.shooting_residual),
        "uncontrolled_dominant": uncontrolled,
        "reference_kp": kp_r, "reference_kd": kd_r, "reference_gains_source": source,
        "reference_gains_dominant_exudyn": float(abs(ef.dominant_multiplier)),
        "reference_gains_dominant_mode": ef.dominant_mode,
        "reference_gains_dominant_reduced": reduced,
        "spectral_radius_all_modes": float(ef.floquet.spectral_radius),
        "undamped_multipliers": int(ef.undamped_count),
        "tuned_kp": tuned.kp, "tuned_kd": tuned.kd, "tuned_dominant": tuned_dominant,
        "tuning_status": tuned.status, "tuning_evaluations": tuned.evaluations,
        "tuning_time_s": tuned.elapsed,
        # the loop's step count and, for --quick, the step-doubling estimate of its response at the
        # tuned gains (tuned_dominant is always at the plant's full count, plant.n_steps)
        "tuning_propagator_steps": loop.n_steps, "propagator_steps": plant.n_steps,
        "tuning_step_doubling_estimate": step_check,
        **verdicts,
    }
    (opts.out / "exudyn.json").write_text(json.dumps({"rows": [row]}, indent=2))
    blocks = [
        text(f"Exudyn ANCF model ({elements} elements), linearised by central differences along its T-periodic "
             "orbit (the built-in model file `single-link`); Floquet multipliers by the exponential-midpoint product "
             "(`magnus2`) in the frozen-modal frame, Richardson-extrapolated. 'dominant' = largest multiplier of "
             "the modes the reduced model has (hub, first bending); "
             + (f"structural damping of the beams: {cfg.damping.describe()}. " if damp else
                "the axial and higher bending modes are undamped (no structural damping) and sit on the unit "
                "circle. ")
             + f"Reference gains: {source}."),
        table(["Ω", "uncontrolled: dominant |ρ|", "reference kp, kd", "reference gains: Exudyn dominant |ρ|",
               "reference gains: reduced max|ρ|", "all modes max|ρ|", "Taguchi on Exudyn: kp, kd",
               "Taguchi on Exudyn: dominant |ρ|", "evals"],
              [[f"{row['omega_over_pi']:.4g}π", f"{uncontrolled:.5f}", f"{kp_r:.4f}, {kd_r:.4f}",
                f"{row['reference_gains_dominant_exudyn']:.5f} ({row['reference_gains_dominant_mode']})",
                f"{reduced:.5f}", f"{row['spectral_radius_all_modes']:.6f}",
                f"{tuned.kp:.4f}, {tuned.kd:.4f}", f"{tuned_dominant:.5f} ({tuned.status})",
                tuned.evaluations]]),
        *([text(f"Quick mode: {samples} collocation samples per period (32 in the full study); "
                + (f"the Taguchi loop ran with {loop.n_steps} propagator steps and the tuned gains were re-evaluated "
                   f"with {plant.n_steps} (the table's value): step-doubling estimate {step_check:.1e}, below a "
                   f"quarter of the tuning tolerance {tcfg.effective_tolerance:.1e}." if loop is not plant else
                   f"the Taguchi loop with {plant.n_steps // 2} propagator steps missed the tuning tolerance "
                   f"{tcfg.effective_tolerance:.1e} by its step-doubling estimate {step_check:.1e} and was repeated "
                   f"with {plant.n_steps}."))] if opts.quick else []),
        text(f"At the reference gains the Exudyn and reduced models differ by "
             f"{relative(row['reference_gains_dominant_exudyn'] / reduced - 1)} in the dominant multiplier."),
        # the whole loop's verdicts (stability.verdict) reconcile 'dominant' with 'all modes max|ρ|'
        text("The whole closed loop (every multiplier, rule of `docs/verdicts.md`): uncontrolled — "
             f"{verdicts['verdict_uncontrolled']['message']}; reference gains — "
             f"{verdicts['verdict_reference']['message']}; Taguchi gains — {verdicts['verdict_tuned']['message']}."),
    ]
    return StageOutput(json="exudyn.json", title=f"Exudyn ANCF model at Ω = {_w(omega)}", blocks=blocks)


# ----------------------------------------------------------------------------- verdicts (stability.verdict)
#: Kelvin-Voigt loss time (s) of the damped rows of the sensitivity stage (mbs_models.damping: zeta ~ 1e-3 at
#: 30 Hz, the order of the material damping of a metal beam's lowest modes).
SENSITIVITY_DAMPING = 1e-5


def _link_definition(cfg: StudyConfig, elements: int, damped: bool = True) -> tuple:
    """The paper's link on the generic path: the built-in model file ``single-link`` with the configured
    manipulator and ``elements``, and (``damped``) the ``[study] damping`` of its beams;
    ``(definition, build options)``."""
    from flexstab.options import EXUDYN_ALIAS, resolve_model_definition

    extra = cfg.damping.build_options() if damped and getattr(cfg.damping, "given", False) else {}
    return resolve_model_definition(EXUDYN_ALIAS, cfg, elements, **extra)


def _whole_loop_verdict(analysis, kp: float, kd: float) -> dict:
    """:func:`stability.verdict.judge_floquet` of the whole closed loop at ``(kp, kd)`` about the orbit of
    ``analysis`` (a :class:`~linearize.analysis.ModelFloquetResult`), with the mode labels, as a dict."""
    from linearize.analysis import analyze

    orbit = analysis.orbit
    return analyze(orbit.model, orbit.omega, kp=kp, kd=kd, samples=orbit.samples, orbit=orbit).verdict.to_dict()


def _stage_sensitivity(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    """The verdict's sensitivity to the mesh (2/4/8 elements; 2/4 in quick mode) and to structural damping
    (none, and ``SENSITIVITY_DAMPING``) at the reference gains, Exudyn link."""
    from linearize.analysis import analyze
    from mbs_models.damping import material_damping_values

    kp, kd, source = _reference_gains(cfg, opts)
    p = cfg.manipulator
    meshes = (2, 4) if opts.quick else (2, 4, 8)
    rows = []
    base = cfg.damping if getattr(cfg.damping, "given", False) else None
    dampings = [("none", 0.0, 0.0)]
    b, a = material_damping_values(SENSITIVITY_DAMPING, p.bending_stiffness, p.axial_stiffness)
    dampings.append((f"β = {SENSITIVITY_DAMPING:g} s", b, a))
    if base is not None:
        b, a = material_damping_values(base.material, p.bending_stiffness, p.axial_stiffness, base.bending, base.axial)
        dampings.append((f"configured: {base.describe()}", b, a))
    for e in meshes:
        orbit = None
        for name, b, a in dampings:
            definition, options = _link_definition(cfg, e, damped=False)
            undamped = b == 0.0 and a == 0.0
            if not undamped:
                options.update(bending_damping=b, axial_damping=a)
            ex = analyze(definition, cfg.omega, kp=kp, kd=kd, samples=16 if opts.quick else 32, verify_orbit=False,
                         orbit=orbit if undamped else None, **options)
            if undamped:
                orbit = ex.orbit
            v = ex.verdict.to_dict()
            rows.append({"elements": e, "damping": name, "bending_damping": b, "axial_damping": a,
                         "verdict": v["verdict"], "spectral_radius": v["spectral_radius"],
                         "spectral_radius_mode": v["spectral_radius_mode"], "undamped_count": v["undamped_count"],
                         "margin": v["margin"], "message": v["message"],
                         "dominant_modulus": float(abs(ex.dominant_multiplier))})
    (opts.out / "sensitivity.json").write_text(json.dumps({"rows": rows, "kp": kp, "kd": kd, "gains_source": source},
                                                          indent=2))
    blocks = [
        text(f"The verdict of the whole closed loop (every multiplier, rule of `docs/verdicts.md`) at the reference "
             f"gains ({source}: kp = {kp:.4f}, kd = {kd:.4f}) for {', '.join(map(str, meshes))} ANCF elements, "
             f"without structural damping and with a Kelvin-Voigt loss time β (bendingDamping = β EI, "
             f"axialDamping = β EA; `--damping`). " + _sensitivity_words(rows)),
        table(["elements", "damping", "verdict", "spectral radius (mode)", "undamped multipliers",
               "dominant |ρ| (hub, bending 1)"],
              [[r["elements"], r["damping"], r["verdict"], f"{r['spectral_radius']:.10g} ({r['spectral_radius_mode']})",
                r["undamped_count"], f"{r['dominant_modulus']:.5f}"] for r in rows]),
    ]
    return StageOutput(json="sensitivity.json", blocks=blocks,
                       title=f"Verdict sensitivity to mesh and damping at Ω = {_w(cfg.omega)}")
def _sensitivity_words(rows: list) -> str:
    """What the sensitivity table shows, per damping, from its rows (never a claim the numbers do not make)."""
    parts = []
    for damping in dict.fromkeys(r["damping"] for r in rows):
        sub = [r for r in rows if r["damping"] == damping]
        verdicts = {r["verdict"] for r in sub}
        where = ", ".join(f"{r['elements']}" for r in sub)
        if len(verdicts) == 1:
            parts.append(f"damping {damping}: {sub[0]['verdict']} at {where} elements")
        else:
            parts.append(f"damping {damping}: " + "; ".join(
                f"{r['verdict']} at {r['elements']} elements ({r['spectral_radius_mode']}, "
                f"|ρ| = {r['spectral_radius']:.6g})" for r in sub) + " -- the verdict depends on the mesh")
    return "Measured: " + "; ".join(parts) + "."


# ----------------------------------------------------------------------------- end of verdicts


def _validation_gains(cfg: StudyConfig, opts: StudyOptions) -> tuple[float, float, str]:
    rec = pv.load_record(opts.out, "exudyn")
    if rec is not None and rec.get("config_hash") == config_hash(cfg) and rec.get("quick") == opts.quick:
        r = json.loads((opts.out / rec["json"]).read_text())["rows"][0]
        return r["tuned_kp"], r["tuned_kd"], "Taguchi on Exudyn (exudyn.json)"
    return _reference_gains(cfg, opts)


def _stage_validation(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    """Multipliers measured from nonlinear Exudyn runs of the tuned closed loop at the study Omega.

    Gains: those tuned on the Exudyn model by the ``exudyn`` stage of this run (``exudyn.json``),
    else the reference gains (see the module docstring).  Measurement:
    :func:`flexstab.validation_runs.validate_multipliers` of the paper's link (the built-in model file
    ``single-link``, as ``flexstab validate``): the one-period map of the
    nonlinear closed loop on the subspace of the compared multipliers, compared with the Exudyn
    linearisation within the measurement's own error bar.
    """
    from flexstab.validation_runs import ValidateOptions, validate_multipliers
    from validation.plots import plot_multiplier_plane

    kp, kd, source = _validation_gains(cfg, opts)
    elements = 2 if opts.quick else min(cfg.elements, 4)
    # three step levels also in quick mode (two give no verdict); --quick starts them at 2e-3 s (about half
    # the integration work of the default step); the step-convergence check and its error bar decide whether
    # that is fine enough, as at any step
    check = ValidateOptions(model="exudyn", omega=cfg.omega, kp=(kp,), kd=(kd,), gains_source=source,
                            elements=elements, step=2e-3 if opts.quick else None, refinements=2, growth_periods=0)
    res = validate_multipliers(check, cfg)
    v, d = res.measurement, res.report
    (opts.out / "validation.json").write_text(json.dumps({"rows": [d]}, indent=2, default=float))
    fig = "validation_multipliers.png"
    plot_multiplier_plane([v], opts.out / fig,
                          titles=[f"Ω = {cfg.omega / math.pi:.4g}π: kp = {kp:.4g}, kd = {kd:.4g}"],
                          suptitle="Multipliers measured from nonlinear Exudyn runs vs predicted")

    blocks = validation_blocks(d, f"Free-hub Exudyn model ({elements} elements) under feed-forward + PD (gains: "
                                  f"{source}).", d.get("steps") or (), fig)
    from flexstab.checks import validation_failures

    return StageOutput(json="validation.json", title=f"Nonlinear validation at Ω = {_w(cfg.omega)}", blocks=blocks,
                       files=(fig, "validation.json"), check_failures=tuple(validation_failures(d)))


def validation_blocks(d: dict, what: str, steps: Sequence[float], fig: str) -> list:
    """Report blocks of a nonlinear multiplier validation (``MultiplierValidation.to_dict()``).

    ``what`` opens the paragraph (the model and its gains), ``steps`` are the generalised-alpha
    steps, ``fig`` the complex-plane figure.
    """
    def z(c):
        return "–" if c is None else f"{c[0]:+.6f}{c[1]:+.6f}i"

    def e(x):
        return "n/a" if x is None else f"{x:.2e}"

    alts = {("rigid reference" if "rigid" in a["name"] else "reduced model"): a["distance"] for a in d["alternatives"]}
    rows = []
    for m in d["multipliers"]:
        rows.append([m["mode"], z(m["predicted"]), z(m.get("measured")), e(m.get("abs_error")),
                     e(m.get("error_bar")), "yes" if m.get("agrees") else "no"])
    blocks = [
        text(what + " The one-period map of the nonlinear closed loop is measured on the subspace of the compared "
             "multipliers (central differences of runs from the periodic orbit perturbed along the predicted Floquet "
             "vectors, generalised-α with ρ∞ = 1 at h = " + ", ".join(f"{h:g}" for h in steps) + " s); its "
             "eigenvalues are compared with the multipliers of the Exudyn linearisation within the measurement's "
             "error bar (Richardson step error + amplitude check + prediction refinement)."
             + (f" Diverged: {d['reason']}." if d["diverged"] else "")),
        table(["mode", "predicted", "measured", "absolute error", "error bar", "agrees"], rows),
    ]
    if alts:
        blocks.append(text("Measured distance to the alternative predictions: "
                           + "; ".join(f"{k}: {e(val)}" for k, val in alts.items()) + "."))
    blocks.append(figure(fig, "Measured (nonlinear Exudyn) and predicted multipliers in the complex plane with the "
                              "unit circle."))
    return blocks


def _stage_two_link(cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    """The built-in two-link arm at the study Omega: see :mod:`flexstab.two_link_report`."""
    from flexstab.two_link_report import stage_two_link

    return stage_two_link(cfg, opts)


#: Registry of the study's stages, in order.
STAGES: dict[str, Callable[[StudyConfig, StudyOptions], StageOutput]] = {
    "table2": _stage_table2,
    "table3": _stage_table3,
    "charts": _stage_charts,
    "transients": _stage_transients,
    "exudyn": _stage_exudyn,
    "validation": _stage_validation,
    "two_link": _stage_two_link,
    "sensitivity": _stage_sensitivity,
}

#: Section titles (a stage's own title may name the Omega or the paper's table).
STAGE_TITLES: dict[str, str] = {
    "table2": "Floquet multipliers without control",
    "table3": "PD gains by Taguchi tuning",
    "charts": "Stability charts",
    "transients": "Transient responses",
    "exudyn": "Exudyn ANCF model",
    "validation": "Nonlinear validation",
    "two_link": "Two-link flexible arm",
    "sensitivity": "Verdict sensitivity to mesh and damping",
}


# ----------------------------------------------------------------------------- report
def _manipulator_line(cfg: StudyConfig) -> str:
    from flexstab.paper_tables import is_paper_manipulator

    m = cfg.manipulator.to_dict()
    units = {"length": "m", "area": "m²", "density": "kg/m³", "second_moment": "m⁴", "youngs_modulus": "Pa",
             "hub_inertia": "kg·m²", "tip_mass": "kg", "joint_damping": "N·m·s/rad", "gravity": "m/s²"}
    parts = [f"{k.replace('_', ' ')} = {v:g} {units.get(k, '')}".rstrip() for k, v in m.items()]
    who = ("the paper's manipulator (Table 1)" if is_paper_manipulator(cfg.manipulator)
           else "a user-defined manipulator (not the Table 1 link of the paper, so nothing below is compared with the paper)")
    return f"Manipulator: {who}; " + ", ".join(parts) + "."


def render_report(out: Path) -> tuple[Path, Path]:
    """Write ``report.md`` and ``report.html`` from ``manifest.json`` and the stage records in ``out``.

    Raises
    ------
    RuntimeError
        If a stage record belongs to another configuration than the manifest, or a file it names
        has changed since the stage wrote it (the report would mix runs).
    """
    out = Path(out)
    manifest = json.loads((out / pv.MANIFEST).read_text())
    chash = manifest["config_hash"]
    cfg_doc = manifest["config"]
    from mbs_models.parameters import ManipulatorParameters

    cfg = StudyConfig(manipulator=ManipulatorParameters(**cfg_doc["manipulator"]), omega=cfg_doc["omega"],
                      target=cfg_doc["target"], kp_range=tuple(cfg_doc["kp_range"]),
                      kd_range=tuple(cfg_doc["kd_range"]), elements=cfg_doc["elements"])
    sections = []
    reused = []
    for name, entry in manifest["stages"].items():
        rec = pv.load_record(out, name)
        title = (rec or {}).get("title") or STAGE_TITLES.get(name, name)
        if entry.get("status") == "failed":
            sections.append((title, [text(f"**Stage failed:** `{entry.get('error', 'unknown error')}`")]))
            continue
        if rec is None:
            raise RuntimeError(f"{out}: stage {name!r} is in the manifest but its record {name}.stage.json is missing")
        if rec.get("config_hash") != chash or rec.get("inputs_hash") != entry.get("inputs_hash"):
            raise RuntimeError(f"{out}: stage {name!r} was computed for another configuration or input "
                               f"({rec.get('config_hash')} != {chash}); the report would mix runs")
        for f, sha in rec["files"].items():
            p = out / f
            if not p.exists() or pv.file_sha(p) != sha:
                raise RuntimeError(f"{out}: {f} changed after stage {name!r} wrote it; the report would mix runs")
        if entry.get("status") == "reused":
            reused.append(title)
        sections.append((title, stage_section(rec, reused=entry.get("status") == "reused")))
    quick = manifest["quick"]
    omega = cfg.omega
    preamble = [
        text(_manipulator_line(cfg)),
        text(f"Fundamental motion q_a(t) = π/2 + (π/2) sin(Ωt); study Ω = {omega / math.pi:.4g}π rad/s "
             f"(T = {2 * math.pi / omega:.4g} s), target ρ_d = {cfg.target:g}. Mode: {'quick' if quick else 'full'}. "
             f"Configuration hash `{chash}`; every number below comes from the JSON file named under its "
             "section (same folder), which carries the same hash."),
        text(f"Started {manifest['started_at']}, finished {manifest.get('finished_at', '?')}; wall time "
             f"{manifest.get('elapsed', float('nan')):.1f} s."
             + (f" Reused from an earlier run with the same inputs: {', '.join(reused)}." if reused else "")),
    ]
    # ---- the verdict block (flexstab.verdict_report): first section of the report
    from flexstab.verdict_report import verdict_blocks, verdict_summary

    computed = {k for k, e in manifest["stages"].items() if e.get("status") in ("computed", "reused")}
    sections.insert(0, ("Verdict", verdict_blocks(verdict_summary(out, omega, computed))))
    # ---- end of the verdict block
    title = "flexstab study report"
    md_path, html_path = out / "report.md", out / "report.html"
    md_path.write_text(to_markdown(title, preamble, sections))
    html_path.write_text(to_html(title, preamble, sections))
    return md_path, html_path


# ----------------------------------------------------------------------------- driver
def _prepare_out(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise ValueError(f"output folder {str(out)!r} cannot be written: {exc.strerror}") from None


#: Chains of stages that each run in a process of their own beside this one when the study runs on
#: several processes (``jobs >= 2``): the Exudyn chain (``validation`` reads the gains ``exudyn``
#: tuned) and the independent two-link section.  Only those processes import Exudyn.
EXUDYN_CHAINS = (("exudyn", "validation"), ("two_link", "sensitivity"))
#: Every stage of :data:`EXUDYN_CHAINS`.
EXUDYN_LANE = tuple(s for chain in EXUDYN_CHAINS for s in chain)
#: Stages left out of a ``quick`` study unless named explicitly (the two-link section: its tuning is
#: ~20 s CPU on the idle machine).
FULL_ONLY = ("two_link",)


def _call_stage(name: str, cfg: StudyConfig, opts: StudyOptions) -> StageOutput:
    """Stage ``name`` of :data:`STAGES` (looked up where it runs: a forked process sees this one's registry)."""
    return StageOutput.of(STAGES[name](cfg, opts))


def _preload(stages: Sequence[str]) -> None:
    """Import before forking what both processes need (matplotlib, pydoe's verified arrays)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401

    if any(s in stages for s in ("table3", "charts", "exudyn")):
        from taguchi.arrays import available_arrays

        available_arrays()  # loads and verifies the catalogue (imports pydoe -> scipy.stats) once
    # the Floquet engine's modules, imported and run once here instead of once per process
    from mbs_models.reduced import ReducedModel
    from stability import floquet

    floquet(ReducedModel(2 * math.pi))


def _lane_worker_init(parent_pid: int, blas: int = 1) -> None:
    """Initializer of the study's Exudyn processes: ``blas`` BLAS threads, and end with the parent."""
    from flexstab.executor import worker_init

    worker_init(parent_pid, blas)


def run_study(cfg: StudyConfig = StudyConfig(), opts: StudyOptions = StudyOptions()) -> StudyResult:
    """Run the study's stages and write ``report.md`` / ``report.html`` to ``opts.out``.

    With ``opts.jobs >= 2``, each chain of :data:`EXUDYN_CHAINS` runs in a process of its own while
    this process runs the other stages in order (with no other stages, the first chain runs here);
    every stage record is written here, as each stage finishes.

    Raises
    ------
    ValueError
        If the output folder cannot be created or an unknown stage is named.
    """
    t0 = time.perf_counter()
    c0 = cpu_now()
    if isinstance(opts.jobs, bool) or not isinstance(opts.jobs, int) or opts.jobs < 1:
        raise ValueError(f"jobs must be a positive integer, got {opts.jobs!r}")
    stages = opts.stages or tuple(s for s in STAGES if not (opts.quick and s in FULL_ONLY))
    unknown = [s for s in stages if s not in STAGES]
    if unknown:
        raise ValueError(f"unknown stage(s) {', '.join(unknown)}; available: {', '.join(STAGES)}")
    out = Path(opts.out)
    _prepare_out(out)
    with folder_lock(out):
        return _run_study(cfg, opts, stages, out, t0, c0)


def _run_study(cfg: StudyConfig, opts: StudyOptions, stages: Sequence[str], out: Path, t0: float,
               c0: float) -> StudyResult:
    """:func:`run_study` in its locked output folder."""
    say = opts.log or (lambda line: None)
    chash = config_hash(cfg)
    code = pv.code_hash()
    old = pv.read_manifest(out)
    if old is not None and old.get("config_hash") != chash:
        say(f"study: {out} held a study of another configuration ({old.get('config_hash')}); "
            "its report is replaced and none of its stages is reused")
    for f in ("report.md", "report.html", "study.json"):  # never leave a report of another run beside this one
        (out / f).unlink(missing_ok=True)
    bar = None
    if opts.progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(stages), desc="study", unit="stage")
    index = {name: i for i, name in enumerate(stages, 1)}
    runner = StageRunner(out, {"config": config_dict(cfg), "config_hash": chash, "code_hash": code,
                               "quick": opts.quick}, order=stages, resume=opts.resume, log=opts.log,
                         tag=lambda name: f"study: [{index[name]}/{len(stages)}] {name}",
                         record_fields={"config_hash": chash, "quick": opts.quick}, stamp=True, bar=bar)

    def stage(name: str, o: StudyOptions) -> Stage:
        def inputs() -> dict:  # evaluated when the stage is about to run
            d = {"stage": name, "config": config_dict(cfg), "quick": opts.quick, "code": code}
            if name == "validation":  # reads the gains tuned by the exudyn stage
                d["gains"] = list(_validation_gains_for_hash(cfg, opts))
            return d

        return Stage(name, functools.partial(_call_stage, name, cfg, o), inputs, STAGE_TITLES[name])

    chains = [[s for s in stages if s in chain] for chain in EXUDYN_CHAINS] if opts.jobs >= 2 else []
    chains = [c for c in chains if c]
    here = [s for s in stages if not any(s in c for c in chains)]
    if not here and chains:  # nothing else to overlap with: the first chain runs here
        here, chains = chains[0], chains[1:]
    remote = replace(opts, progress=False, log=None)
    from flexstab.threads import blas_threads

    try:
        runner.run([stage(n, opts) for n in here], [[stage(n, remote) for n in c] for c in chains],
                   preload=lambda: _preload(stages), initializer=_lane_worker_init,
                   initargs=(os.getpid(), blas_threads()))
    finally:
        if bar is not None:
            bar.close()
    elapsed = time.perf_counter() - t0
    cpu = cpu_now() - c0
    runner.finish(elapsed=elapsed, cpu=cpu)
    md, ht = render_report(out)
    from flexstab.verdict_report import verdict_summary

    entries = runner.manifest["stages"]
    computed = {k for k, e in entries.items() if e.get("status") in ("computed", "reused")}
    verdict = verdict_summary(out, cfg.omega, computed)
    results = runner.summaries()
    (out / "study.json").write_text(json.dumps({"verdict": verdict, "elapsed": elapsed, "cpu": cpu, "quick": opts.quick,
                                                "jobs": opts.jobs, "config_hash": chash, "stages": results},
                                               indent=2, default=str))
    return StudyResult(out, md, ht, results, elapsed)


def _validation_gains_for_hash(cfg: StudyConfig, opts: StudyOptions) -> tuple:
    """The source of the validation gains (for the stage's input hash) without computing any."""
    rec = pv.load_record(opts.out, "exudyn")
    if rec is not None and rec.get("config_hash") == config_hash(cfg) and rec.get("quick") == opts.quick:
        return ("exudyn", rec["inputs_hash"])
    return ("reference",)
