"""Stability charts as a library call: both charts of a model, computed, plotted and summarised.

:func:`make_charts` draws max|rho| over the (kp, kd) grid (with the Taguchi path) and against Omega
for the reduced model, the Exudyn link or a model file (:func:`model_charts`), from a
:class:`ChartOptions`; ``flexstab chart`` and both studies call it.  The sweeps are resumable
(:mod:`flexstab.charts`): their stores are keyed by everything that changes the numbers.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Union

from flexstab.options import check_model_arg, check_range_arg, ensure_out_dir

__all__ = ["ChartOptions", "make_charts", "model_charts", "check_chart_options", "ChartedDriveObjective"]

Gains = Union[None, float, tuple]


@dataclass(frozen=True)
class ChartOptions:
    """What :func:`make_charts` draws (``None``: the default of the model or of the configuration).

    Attributes
    ----------
    model : str
        ``reduced``, ``exudyn``, a built-in model file name or a model file ``PATH.py``.
    out : Path
        Output folder (created).
    omega : float, optional
        Omega of the gain chart (default the configuration's).
    kp_range, kd_range : (float, float), optional
        Gain ranges (default the configuration's).
    grid : int, optional
        Points per gain axis (41; Exudyn and model files 11).
    target : float, optional
        rho_d of the contour and of the Taguchi path (default the configuration's).
    omega_range : (float, float), optional
        Omega range of the second chart (pi..10pi; Exudyn pi..8pi; model files 0.5..1.5 Omega).
    omega_points : int, optional
        Omegas of the second chart (181; Exudyn 8; model files 9).
    kp, kd : float or tuple, optional
        Fixed gains of the Omega chart (default tuned); model files: one value or one per drive, the
        gains of the drives the gain chart does not vary (default 0).
    no_taguchi : bool
        Do not tune (no Taguchi path).
    constants : str
        The reduced model's constants (``auto``, ...).
    elements : int, optional
        ANCF elements (Exudyn and built-in models).
    drive : str, optional
        Model files: the drive whose (kp, kd) the gain chart varies (default the first), or ``all``.
    samples, steps : int, optional
        Model files: collocation samples per period and magnus2 sub-intervals per evaluation.
    scheduler : str, optional
        Dask scheduler address of the sweeps (model files: of the gain chart and its Taguchi path).
    workers : int, optional
        Local worker processes (model files: of the gain chart and its Taguchi path; default serial).
    """

    model: str = "reduced"
    out: Path = Path("results")
    omega: Optional[float] = None
    kp_range: Optional[tuple] = None
    kd_range: Optional[tuple] = None
    grid: Optional[int] = None
    target: Optional[float] = None
    omega_range: Optional[tuple] = None
    omega_points: Optional[int] = None
    kp: Gains = None
    kd: Gains = None
    no_taguchi: bool = False
    constants: str = "auto"
    elements: Optional[int] = None
    drive: Optional[str] = None
    samples: Optional[int] = None
    steps: Optional[int] = None
    scheduler: Optional[str] = None
    workers: Optional[int] = None


def _omega(opts: ChartOptions, cfg: Any) -> float:
    """The one Omega rule of every command: the chart's Omega if given, else ``[study] omega`` (2pi)."""
    return float(opts.omega) if opts.omega is not None else float(cfg.omega)


def make_charts(opts: ChartOptions, cfg: Any, progress: Any = True) -> dict:
    """Compute and plot both charts of ``opts.model`` for the configuration ``cfg``
    (a :class:`~flexstab.config.StudyConfig`); return the JSON-ready summary.

    Raises
    ------
    ValueError
        Bad options (before any numerical work).
    """
    check_chart_options(opts)  # before any numerical import
    model = opts.model
    if model != "reduced":
        return model_charts(opts, cfg, progress=progress)
    from flexstab.charts import (
        ReducedRadius, check_grid, gain_chart, omega_chart, plot_gain_chart,
        plot_omega_chart,
    )
    from flexstab.executor import make_executor
    from mbs_models.reduced import ReducedModel
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    for flag in ("drive", "samples", "steps"):
        if getattr(opts, flag) is not None:
            raise ValueError(f"--{flag} applies to model files only")
    fixed = {}
    for flag in ("kp", "kd"):
        v = getattr(opts, flag)
        if isinstance(v, (list, tuple)):
            if len(v) != 1:
                raise ValueError(f"--{flag}: --model {model} has one drive (the hub), got {len(v)} values")
            v = float(v[0])
        fixed[flag] = v
    omega = _omega(opts, cfg)
    kp_rng = tuple(opts.kp_range) if opts.kp_range else cfg.kp_range
    kd_rng = tuple(opts.kd_range) if opts.kd_range else cfg.kd_range
    if min(kp_rng) < 0 or min(kd_rng) < 0:
        raise ValueError("gain ranges must be >= 0")
    grid = opts.grid if opts.grid is not None else 41
    n_omega = opts.omega_points if opts.omega_points is not None else 181
    kp = check_grid(*kp_rng, grid, "kp")
    kd = check_grid(*kd_rng, grid, "kd")
    w_lo, w_hi = opts.omega_range if opts.omega_range else (math.pi, 10 * math.pi)
    omegas = check_grid(w_lo, w_hi, n_omega, "omega")
    target = opts.target if opts.target is not None else cfg.target
    out = ensure_out_dir(opts.out)
    # the resumable stores are keyed by everything that changes the numbers
    import hashlib

    fingerprint = hashlib.sha1(
        json.dumps([cfg.manipulator.to_dict(), opts.constants], sort_keys=True).encode()
    ).hexdigest()[:8]
    tag = f"w{omega:.6g}_{opts.constants}_{fingerprint}"
    task = ReducedRadius(cfg.manipulator, opts.constants)
    omega_task = task
    objective = GainObjective(ReducedModel(omega, params=cfg.manipulator, constants=opts.constants))
    label = "linearised reduced model"

    path = None
    tuned = None
    if not opts.no_taguchi:
        tuned = taguchi_tune(objective, TuningConfig(target=target, kp_range=kp_rng, kd_range=kd_rng),
                             progress=progress)
        path = [it.incumbent_gains for it in tuned.iterations]
    n_tasks = kp.size * kd.size
    kind = "dask" if opts.scheduler else "auto"
    with make_executor(kind, max_workers=opts.workers, scheduler=opts.scheduler, n_tasks=n_tasks) as ex:
        gc = gain_chart(task, omega, kp, kd, ex, out / f"chart_gains_{tag}.jsonl", target=target,
                        progress=progress)
        gkp = fixed["kp"] if fixed["kp"] is not None else (tuned.kp if tuned else 0.0)
        gkd = fixed["kd"] if fixed["kd"] is not None else (tuned.kd if tuned else 0.0)
        otag = tag.split("_", 1)[1]
        oc = omega_chart(omega_task, omegas, gkp, gkd, ex, out / f"chart_omega_{otag}_{gkp:.6g}_{gkd:.6g}.jsonl",
                         progress=progress)
    # figure and summary names identify every input that changes what is drawn (grid, ranges, target,
    # Omega range, gains), so a coarse chart never overwrites the study's chart of the same system
    drawn = hashlib.sha1(json.dumps(
        [tag, kp.tolist(), kd.tolist(), target, omegas.tolist(), gkp, gkd, bool(opts.no_taguchi)]
    ).encode()).hexdigest()[:8]
    name = f"{tag}_{kp.size}x{kd.size}_{drawn}"
    png1 = plot_gain_chart(gc, out / f"chart_gains_{name}.png", path, label=label)
    png2 = plot_omega_chart(oc, out / f"chart_omega_{name}.png", label=label,
                            ylabel="max|ρ| (spectral radius)")
    summary = {"gain_chart": gc.to_dict(), "omega_chart": oc.to_dict(),
               "taguchi_path": [list(p) for p in path] if path else None,
               "inputs": {"manipulator": cfg.manipulator.to_dict(), "constants": opts.constants,
                          "model": "reduced", "omega": omega, "grid": [kp.size, kd.size],
                          "kp_range": list(kp_rng), "kd_range": list(kd_rng), "target": target,
                          "omega_range": [float(w_lo), float(w_hi)], "omega_points": int(omegas.size)},
               "figures": [str(png1), str(png2)], "json": str(out / f"chart_{name}.json")}
    (out / f"chart_{name}.json").write_text(json.dumps(summary))
    return summary


def check_chart_options(opts: ChartOptions) -> None:
    """The checks of the options alone (no configuration, no model): grid sizes, counts, ranges.

    Raises
    ------
    ValueError
        One line naming the option (as ``flexstab chart`` spells it) and the problem.
    """
    for flag, minimum in (("grid", 2), ("omega_points", 2), ("samples", 4), ("steps", 1), ("workers", 1)):
        v = getattr(opts, flag)
        if v is not None and v < minimum:
            raise ValueError(f"--{flag.replace('_', '-')} must be >= {minimum}, got {v}")
    for flag in ("kp_range", "kd_range"):
        check_range_arg(getattr(opts, flag), "--" + flag.replace("_", "-"))
    check_model_arg(opts.model)
    w = opts.omega_range
    if w is not None and not w[0] < w[1]:
        raise ValueError(f"--omega-range: omega range is empty or inverted: LO = {w[0]:g}, HI = {w[1]:g}")


def _fixed_gains(values, n_drives: int, flag: str) -> tuple:
    """``--kp``/``--kd`` of a model file: one value for every drive, or one per drive (default 0)."""
    if values is None:
        return (0.0,) * n_drives
    if len(values) == 1:
        return tuple(values) * n_drives
    if len(values) != n_drives:
        raise ValueError(f"--{flag}: the model has {n_drives} drive(s); give one value or {n_drives}, got {len(values)}")
    return tuple(values)


@dataclass(frozen=True)
class ChartedDriveObjective:
    """Picklable Taguchi objective of a model-file chart: ``(kp, kd)`` of the charted drive -> the response
    at the chart's Omega (``task``: a :class:`flexstab.charts.ModelRadius`)."""

    task: Any
    omega: float

    def __call__(self, gains) -> float:
        return self.task({"omega": self.omega, "kp": float(gains[0]), "kd": float(gains[1])})


def model_charts(opts: ChartOptions, cfg: Any, progress: Any = True) -> dict:
    """Both charts of a model file (``--model PATH.py`` or a built-in model file).

    Gain chart: the dominant labelled multiplier over the (kp, kd) grid of one drive (``--drive``)
    with the other drives at ``--kp``/``--kd``, at the chart Omega.  Omega chart: uncontrolled and
    at the tuned (else the fixed) gains, each Omega's orbit continued from the nearest one computed.
    The gain chart and its Taguchi path run through the executor of ``opts.workers``/``opts.scheduler``
    (default serial), the Omega chart in this process.  Returns the JSON-ready summary.
    """
    import dataclasses
    import hashlib

    from flexstab.charts import (ModelPlants, ModelRadius, check_grid, dominant_ylabel, gain_chart, omega_chart,
                                 plot_gain_chart, plot_omega_chart)
    from flexstab.executor import make_executor
    from flexstab.options import resolve_model_definition
    from linearize.hill_plant import HillModelPlant
    from linearize.periodic_orbit import DEFAULT_SAMPLES
    from taguchi.tuning import TuningConfig, check_gain_range, taguchi_tune

    # every option is checked before the first orbit
    if opts.scheduler:
        from flexstab.executor import validate_scheduler_address

        validate_scheduler_address(opts.scheduler)
    omega = _omega(opts, cfg)
    kp_rng = check_gain_range(opts.kp_range if opts.kp_range else cfg.kp_range, "--kp-range")
    kd_rng = check_gain_range(opts.kd_range if opts.kd_range else cfg.kd_range, "--kd-range")
    grid = opts.grid if opts.grid is not None else 11
    kp = check_grid(*kp_rng, grid, "kp")
    kd = check_grid(*kd_rng, grid, "kd")
    exudyn = opts.model == "exudyn"  # the paper's link: the paper's Omega range (pi .. 8 pi, 8 points)
    default_range = (math.pi, 8 * math.pi) if exudyn else (0.5 * omega, 1.5 * omega)
    w_lo, w_hi = opts.omega_range if opts.omega_range else default_range
    omegas = check_grid(w_lo, w_hi, opts.omega_points if opts.omega_points is not None else (8 if exudyn else 9),
                        "omega")
    samples = opts.samples if opts.samples is not None else DEFAULT_SAMPLES
    if isinstance(samples, bool) or samples < 4 or samples % 2:
        raise ValueError(f"--samples must be an even integer >= 4, got {samples}")
    steps = opts.steps
    if steps is not None and steps < 1:
        raise ValueError(f"--steps must be >= 1, got {steps}")
    target = opts.target if opts.target is not None else cfg.target
    definition, options = resolve_model_definition(opts.model, cfg, opts.elements)
    out = ensure_out_dir(opts.out)

    plants = ModelPlants(definition, options, samples=samples)
    drives = plants.linearised(omega)[0].drive_names  # the orbit at the chart's Omega: the drives, the first check
    nd = len(drives)
    # the plant rule of tune and study --model (flexstab.plants.plant_for) with the tuning configuration they
    # build from the same ranges and target: same method and discretisation, so the same response
    tcfg = TuningConfig(target=target, ranges=(tuple(kp_rng), tuple(kd_rng)) * nd) if nd else None
    task = ModelRadius(plants, config=tcfg, steps=steps)
    if opts.drive in (None, "all"):
        idx = None if opts.drive == "all" else 0
    elif opts.drive in drives:
        idx = drives.index(opts.drive)
    else:
        raise ValueError(f"--drive {opts.drive!r}: the model's drives are {', '.join(drives) or '(none)'}")
    fkp, fkd = _fixed_gains(opts.kp, nd, "kp"), _fixed_gains(opts.kd, nd, "kd")
    task = dataclasses.replace(task, drive=idx, fixed_kp=fkp, fixed_kd=fkd)  # same plants (the cache object)
    charted = ("all drives" if idx is None else drives[idx]) if nd else None

    from flexstab.provenance import code_hash

    source = definition.source
    code = hashlib.sha1(Path(source).read_bytes()).hexdigest()[:8] if source else definition.name
    # the resumable stores are keyed by everything that changes the numbers: the model file, its
    # options, the discretisation and the package's own source (a changed engine starts a new store)
    # (the plant rule's inputs: fixed steps, or the ranges and target it chooses the discretisation from)
    fingerprint = hashlib.sha1(json.dumps(
        [definition.name, code, repr(sorted(options.items(), key=lambda kv: kv[0])), samples, steps,
         repr(tcfg) if steps is None else None, code_hash()]
    ).encode()).hexdigest()[:8]
    tag = f"{definition.name}_w{omega:.6g}_{fingerprint}"
    choice = task.plants.choice(omega, task.config, task.steps)
    plant, steps_choice = choice.plant, choice.steps
    hill = isinstance(plant, HillModelPlant)
    method = (f"Hill's method, {plant.harmonics} harmonics" if hill else f"{plant.n_steps} magnus2 steps")
    label = f"model {definition.name} (dominant labelled multiplier, {method})"

    path = tuned = None
    gc = None
    # the gain chart and its Taguchi path share the plant at the chart's Omega: its runs go to the executor
    # (the task pickles the plants by value, the model as its file's path); the Omega chart continues each
    # orbit from the nearest one computed, so it runs in this process
    kind = "dask" if opts.scheduler else ("process" if (opts.workers or 1) > 1 else "serial")
    with make_executor(kind, max_workers=opts.workers, scheduler=opts.scheduler) as ex:
        if nd:
            if not opts.no_taguchi:
                tuned = taguchi_tune(ChartedDriveObjective(task, float(omega)),
                                     TuningConfig(target=target, kp_range=kp_rng, kd_range=kd_rng), executor=ex,
                                     progress=progress)
                path = [it.incumbent_gains for it in tuned.iterations]
            ctag = f"{tag}_{'all' if idx is None else idx}_" + hashlib.sha1(
                json.dumps([fkp, fkd]).encode()).hexdigest()[:6]
            gc = gain_chart(task, omega, kp, kd, ex, out / f"chart_gains_{ctag}.jsonl", target=target,
                            progress=progress)
    if tuned is not None:
        gkp, gkd = task.gains(tuned.kp, tuned.kd, nd)
    else:
        gkp, gkd = list(fkp), list(fkd)
    otag = hashlib.sha1(json.dumps([gkp, gkd]).encode()).hexdigest()[:6]
    oc = omega_chart(task, omegas, gkp, gkd, None, out / f"chart_omega_{tag}_{otag}.jsonl", progress=progress)
    # discretisation check at the chart point of the Omega chart's gains.  ModelPlant: the value is the
    # Richardson-extrapolated exponential midpoint (4th order, error ~ 16/15 |r_n - r_2n| asymptotically);
    # 4/3 |r_n - r_2n| bounds the error for any observed order >= 2 (2^p / (2^p - 1) falls with p).
    # Hill: the relative H vs H/2 change (spectral convergence: it bounds the error of H/2, so over-states
    # that of H) times the modulus
    hill_estimate = None
    if hill:
        m = plant.measure(gkp, gkd, error_estimate=True)
        hill_estimate = float(m.hill_error_estimate)
        estimate = hill_estimate * abs(m.dominant)
    else:
        from stability.refine import pair_estimate

        r_n = plant.spectral_measure(gkp, gkd)
        r_2n = dataclasses.replace(plant, n_steps=2 * plant.n_steps).spectral_measure(gkp, gkd)
        estimate = pair_estimate(r_n, r_2n)
    drawn = hashlib.sha1(json.dumps(
        [tag, charted, fkp, fkd, kp.tolist(), kd.tolist(), target, omegas.tolist(), gkp, gkd, bool(opts.no_taguchi)]
    ).encode()).hexdigest()[:8]
    name = f"{tag}_{kp.size}x{kd.size}_{drawn}"
    figures = []
    if gc is not None:
        figures.append(str(plot_gain_chart(gc, out / f"chart_gains_{name}.png", path, label=label,
                                           drive="" if nd == 1 else charted)))
    figures.append(str(plot_omega_chart(oc, out / f"chart_omega_{name}.png", label=label,
                                        ylabel=dominant_ylabel(plants.linearised(omega)[0]))))
    summary = {"gain_chart": gc.to_dict() if gc is not None else None, "omega_chart": oc.to_dict(),
               "taguchi_path": [list(p) for p in path] if path else None,
               # kp, kd: every drive's gains (the JSON typing rule), the charted drive's tuned, the others fixed
               "tuned": ({"kp": list(gkp), "kd": list(gkd), "response": tuned.spectral_radius, "status": tuned.status,
                          "evaluations": tuned.evaluations} if tuned is not None else None),
               "drives": list(drives), "charted_drive": charted, "fixed_kp": list(fkp), "fixed_kd": list(fkd),
               "response_method": "hill" if hill else "magnus2",
               "harmonics": plant.harmonics if hill else None,
               # stable fields; for Hill (no propagator) they hold the magnus2 labelling steps and the absolute
               # H vs H/2 estimate (README "Charts of a model file"), so tune's names are added beside them
               "propagator_steps": plant.label_steps if hill else plant.n_steps,
               "propagator_error_estimate": estimate,
               "label_steps": plant.label_steps if hill else None,
               "hill_error_estimate": hill_estimate,  # relative, H vs H/2 at the chart's gains (as tune's)
               "propagator_choice": steps_choice.to_dict() if steps_choice is not None else None,
               "inputs": {"model": opts.model, "source": source, "options": {k: repr(v) for k, v in options.items()},
                          "omega": omega, "grid": [kp.size, kd.size], "kp_range": list(kp_rng),
                          "kd_range": list(kd_rng), "target": target, "omega_range": [float(w_lo), float(w_hi)],
                          "omega_points": int(omegas.size), "samples": samples},
               "figures": figures, "json": str(out / f"chart_{name}.json")}
    if exudyn:
        summary["inputs"]["manipulator"] = cfg.manipulator.to_dict()
    if gc is None:
        summary["note"] = "the model has no drives: no gain chart (the Omega chart's two curves coincide)"
    from stability.serialization import json_ready

    (out / f"chart_{name}.json").write_text(json.dumps(json_ready(summary)))
    return summary


