"""Tuning the PD gains: the library half of ``flexstab tune`` and of ``flexstab study --model``.

:func:`tune_gains` runs the tuning of a :class:`TuneOptions` (the reduced model, the Exudyn link or a
model file) with its independent re-check and the whole loop's verdict, :func:`robust_tuning` the robust
design (``tune --robust``), and :func:`check_failure` says why a result is not accepted.
:func:`tune_model_plant` tunes the ``2 N`` gains of a plant with ``N`` drives (one ``(kp, kd)`` pair per
drive, :class:`taguchi.tuning.GainObjective`) and, for a time-stepping plant, checks the tuned response with twice the
propagator steps; :func:`factor_ranges` gives the factors' names and ranges, :func:`build_plant` the
plant of a model name and :func:`unreachable_mode` the multiplier no drive can move.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Optional

from flexstab.options import check_model_arg, check_range_arg, gain_pairs, gains_as_lists, model_route, resolve_damping

if TYPE_CHECKING:
    from taguchi.tuning import TuningConfig

logger = logging.getLogger(__name__)

__all__ = ["TuneOptions", "tune_gains", "check_tune_options", "robust_tuning", "whole_loop_fields", "check_failure",
           "build_plant", "FallbackRecorder", "factor_ranges", "RESTART_WIDTH", "tune_model_plant",
           "unreachable_mode", "model_plant_executor"]


@dataclass(frozen=True)
class TuneOptions:
    """What :func:`tune_gains` (and :func:`robust_tuning`) tunes (``None``: the configuration's value).

    Attributes
    ----------
    model : str
        ``reduced``, ``exudyn``, a built-in model file name or a model file ``PATH.py``.
    omega : float, optional
        Frequency of the periodic motion (rad/s).
    constants : str
        The reduced model's mode constants (``auto``, ``paper``, ``derived``).
    target : float, optional
        rho_d.
    kp_range, kd_range : (float, float), optional
        Initial range of every drive's kp and kd.
    factor_range : tuple of str
        ``NAME=LO,HI`` ranges of single factors (override ``kp_range``/``kd_range`` for them).
    array : str, optional
        Orthogonal array (default L9).
    tolerance : float, optional
        Tuning tolerance (default 1e-3 rho_d).
    max_evaluations : int
        Floquet evaluations per tuning pass.
    elements : int, optional
        ANCF elements (Exudyn and built-in models).
    damping : str, optional
        Structural damping of the beams (:func:`mbs_models.damping.parse_damping`; default the configuration's).
    scheduler : str, optional
        Dask scheduler address (every model; a model file must be readable at the same path on the workers).
    workers : int, optional
        Local worker processes (model files: :func:`model_plant_executor`).
    compare : bool
        Also run the direct optimisers (Nelder-Mead, differential evolution).
    grid : int, optional
        Robust design: points per noise factor of the worst-case grid (default ``[robust] grid``).
    """

    model: str = "reduced"
    omega: Optional[float] = None
    constants: str = "auto"
    target: Optional[float] = None
    kp_range: Optional[tuple] = None
    kd_range: Optional[tuple] = None
    factor_range: tuple = ()
    array: Optional[str] = None
    tolerance: Optional[float] = None
    max_evaluations: int = 600
    elements: Optional[int] = None
    damping: Optional[str] = None
    scheduler: Optional[str] = None
    workers: Optional[int] = None
    compare: bool = False
    grid: Optional[int] = None


def _omega(opts: TuneOptions, cfg: Any) -> float:
    """The one Omega rule of every command: the option if given, else ``[study] omega`` (2pi)."""
    return float(opts.omega) if opts.omega is not None else float(cfg.omega)


def build_plant(model: str, cfg, omega: float, constants: str, elements=None, damping=None):
    """The plant object (``with_gains(kp, kd)``) for the chosen model (``damping``: a
    :class:`~mbs_models.damping.DampingSpec`, default ``cfg.damping``)."""
    damping = damping if damping is not None else getattr(cfg, "damping", None)
    given = damping is not None and damping.given
    if model != "reduced":
        from flexstab.options import resolve_model_definition
        from linearize.analysis import model_plant

        definition, options = resolve_model_definition(model, cfg, elements,
                                                       **(damping.build_options() if given else {}))
        plant = model_plant(definition, omega, **options)
        if not plant.drives:
            raise ValueError(f"the model {model!r} has no drives: there are no PD gains to tune")
        return plant
    if given:
        raise ValueError("--damping applies to the Exudyn and model-file models, not to --model reduced")
    from mbs_models.reduced import ReducedModel

    return ReducedModel(omega=omega, params=cfg.manipulator, constants=constants)


class _Recorded:
    """``fn(*args) -> (value, new fallback records of plant)`` (picklable; ``fn`` and ``plant`` travel together,
    so in a worker ``plant`` is the copy ``fn`` evaluates)."""

    def __init__(self, fn, plant) -> None:
        self.fn, self.plant = fn, plant

    def __call__(self, *args):
        n = len(self.plant.fallback_runs)
        value = self.fn(*args)
        new = self.plant.fallback_runs[n:]
        del self.plant.fallback_runs[n:]  # returned here: not counted again from an in-process plant
        return value, new


class FallbackRecorder:
    """An executor whose ``map`` also collects the Hill plant's :attr:`fallback_runs` of every run into
    :attr:`records` (they are made in the worker's copy of the plant); anything else is the inner executor's."""

    def __init__(self, inner, plant) -> None:
        self.inner, self.plant, self.records = inner, plant, []

    def map(self, fn, *iterables, **kwargs):
        pairs = list(self.inner.map(_Recorded(fn, self.plant), *iterables, **kwargs))
        for _, new in pairs:
            self.records.extend(new)
        return iter([value for value, _ in pairs])

    def __getattr__(self, name):
        return getattr(self.inner, name)


def factor_ranges(n_drives: int, kp_range, kd_range, specs) -> tuple[tuple[str, ...], tuple]:
    """Factor names and initial ranges of the tuning of ``n_drives`` (kp, kd) pairs.

    ``kp_range``/``kd_range`` apply to every drive; each ``NAME=LO,HI`` of
    ``specs`` replaces one factor's range.  Ranges are checked by
    :class:`taguchi.tuning.TuningConfig`.

    Raises
    ------
    ValueError
        A malformed ``NAME=LO,HI``, an unknown or repeated factor name.
    """
    from taguchi.tuning import default_factor_names

    names = default_factor_names(2 * n_drives)
    ranges = [tuple(kp_range) if j % 2 == 0 else tuple(kd_range) for j in range(2 * n_drives)]
    seen: set = set()
    for spec in specs or ():
        name, sep, rest = str(spec).partition("=")
        name = name.strip()
        parts = rest.split(",")
        if not sep or len(parts) != 2:
            raise ValueError(f"--range expects NAME=LO,HI like {names[-1]}=0,10, got {spec!r}")
        if name not in names:
            raise ValueError(f"--range {spec!r}: unknown factor {name!r}; the factors are {', '.join(names)}")
        if name in seen:
            raise ValueError(f"--range: factor {name!r} given twice")
        seen.add(name)
        try:
            lo, hi = (float(v) for v in parts)
        except ValueError:
            raise ValueError(f"--range {spec!r}: LO and HI must be numbers") from None
        ranges[names.index(name)] = (lo, hi)
    return names, tuple(ranges)


#: Width (fraction of each initial range) of the ranges of a tuning pass restarted with twice the steps.
RESTART_WIDTH = 0.25


def tune_model_plant(plant: Any, tcfg: "TuningConfig", *, executor: Any = None,
                     progress: Any = False) -> tuple[Any, Any, list]:
    """Taguchi tuning of a model-file plant (:func:`flexstab.plants.plant_for`), with the step-doubling
    check at the tuned gains for a time-stepping plant.

    A :class:`~linearize.hill_plant.HillModelPlant` has no propagator steps to refine: one pass, and
    ``passes`` is empty.  A ``plant`` with ``n_steps`` (a :class:`~linearize.analysis.ModelPlant`,
    e.g. from :func:`flexstab.plants.propagator_steps`) is tuned
    with :class:`taguchi.tuning.GainObjective`; at the tuned gains its response with ``2 n`` propagator steps is
    compared (error estimate ``4/3 |r_n - r_2n|``: the Richardson-extrapolated 4th-order value has
    ``~ 16/15 |r_n - r_2n|``, and 4/3 bounds the error for any order >= 2, see
    :func:`flexstab.plants.propagator_steps`); above a quarter of the tolerance the tuning runs again
    from the initial ranges with ``2 n`` steps (the evaluation budget is per pass), up to
    :data:`flexstab.plants.MAX_TUNING_STEPS`.

    Returns
    -------
    (TaguchiResult, plant, passes)
        The last pass's result, the plant it used and one dict per pass (``propagator_steps``,
        ``evaluations``, ``spectral_radius``, ``check_2n``, ``converged``).
    """
    import dataclasses

    from stability.refine import pair_estimate
    from taguchi.tuning import GainObjective, recentre, taguchi_tune

    from flexstab.plants import MAX_TUNING_STEPS

    from linearize.hill_plant import HillModelPlant

    if isinstance(plant, HillModelPlant):  # no propagator steps to refine: one pass
        return taguchi_tune(GainObjective(plant), tcfg, executor=executor, progress=progress), plant, []
    n_drives = len(plant.drives)
    passes: list = []
    full_cfg = tcfg
    while True:
        res = taguchi_tune(GainObjective(plant), tcfg, executor=executor, progress=progress)
        kp, kd = gain_pairs(res.gains, n_drives)
        finer = dataclasses.replace(plant, n_steps=2 * plant.n_steps)
        r2 = finer.spectral_measure(kp, kd)
        passes.append({"propagator_steps": plant.n_steps, "evaluations": res.evaluations,
                       "spectral_radius": res.spectral_radius, "check_2n": r2, "converged": res.converged})
        if not res.converged and tcfg is not full_cfg:
            # the narrowed window of a warm restart missed the target: this pass again from the full ranges
            logger.info("warm restart with %d steps did not converge: tuning again from the initial ranges",
                        plant.n_steps)
            tcfg = full_cfg
            continue
        if (not res.converged or pair_estimate(res.spectral_radius, r2) <= 0.25 * tcfg.effective_tolerance
                or finer.n_steps > MAX_TUNING_STEPS):
            return res, plant, passes
        logger.info("tuned response %.6g with %d steps, %.6g with %d: tuning again with %d steps",
                    res.spectral_radius, plant.n_steps, r2, finer.n_steps, finer.n_steps)
        plant = finer
        # warm restart: the finer propagator moves the answer by about the step-doubling difference, so the
        # next pass starts from the tuned gains with ranges narrowed to RESTART_WIDTH of each initial width
        # (shifted to stay inside it) instead of from scratch
        narrowed = tuple(recentre(g, RESTART_WIDTH * (hi - lo), (lo, hi))
                         for g, (lo, hi) in zip(res.gains, full_cfg.factor_ranges))
        tcfg = dataclasses.replace(full_cfg, ranges=narrowed)


def model_plant_executor(hill: bool, workers: Optional[int]) -> str:
    """The local executor kind of a model-file plant's runs (``--scheduler`` aside: Dask).

    A plant pickles by value (orbit and linearisation as arrays; the model as its file's path and options,
    loaded again in a worker only if called, :class:`mbs_models.model_file.ModelDefinition`), so its runs go
    to worker processes like the reduced model's: ``workers > 1`` asks for a process pool; by default a Hill
    plant (seconds per run) uses one and a time-stepping plant runs serially (``workers == 1`` always does).
    """
    if workers == 1:
        return "serial"
    return "process" if hill or (workers is not None and workers > 1) else "serial"


def unreachable_mode(orbit: Any, omega: float, tcfg: Any) -> Optional[dict]:
    """The closed loop's largest multiplier at the centre of the gain ranges, when it belongs to a mode
    no drive can move (:func:`linearize.analysis.drive_movable`): PD gains cannot bring the spectral
    radius below it, and the tuning works on the dominant multiplier of the modes the drives move.

    Returns
    -------
    dict or None
        ``modulus``, ``mode`` (label), ``drive_shares``, ``gains`` (the range centre), ``tuned_mode`` and
        ``tuned_modulus`` (the dominant multiplier the tuning works on), and a one-line ``message``;
        ``None`` when the largest multiplier is a mode a drive moves.
    """
    import numpy as np

    from linearize.analysis import analyze, drive_movable
    from linearize.periodic_orbit import PeriodicOrbit

    if not isinstance(orbit, PeriodicOrbit):
        return None  # a plant without a model-file orbit (e.g. a stand-in): nothing to label
    from stability.gains import Gains

    centre = [0.5 * (lo + hi) for lo, hi in tcfg.factor_ranges]
    n = len(orbit.drive_names)
    mid = Gains.from_interleaved(centre)
    r = analyze(None, omega, kp=list(mid.kp), kd=list(mid.kd), orbit=orbit)
    top = r.modes[0] if r.modes else None
    if top is None or drive_movable(top, orbit.drive_names):
        return None
    j = int(np.argmin(np.abs(np.asarray(r.floquet.multipliers) - r.dominant_multiplier)))
    tuned = r.modes[j]
    shares = ", ".join(f"{k} {v:.2f}" for k, v in top.drive_shares.items())
    gains = ", ".join(f"{name} = {v:.4g}" for name, v in zip(tcfg.names, centre))
    msg = (f"note: at the range centre ({gains}) the closed loop's largest multiplier |rho| = "
           f"{float(r.floquet.spectral_radius):.5g} belongs to '{top.mode}', a mode no drive moves "
           f"(drive shares {shares}): PD gains cannot bring max|rho| below it; tuning the dominant multiplier "
           f"of the modes the drives move ('{tuned.mode}', |rho| = {abs(r.dominant_multiplier):.5g})")
    return {"modulus": float(r.floquet.spectral_radius), "mode": top.mode,
            "drive_shares": dict(top.drive_shares), "gains": centre[: 2 * n],
            "tuned_mode": tuned.mode, "tuned_modulus": float(abs(r.dominant_multiplier)), "message": msg}


def robust_tuning(opts: TuneOptions, cfg: Any) -> dict:
    """``tune --robust``: nominal vs robust gains, judged over the ``[robust]`` noise grid of ``cfg``."""
    from flexstab.executor import make_executor
    from flexstab.robust import ReducedNoisePlant, compare_nominal_robust
    from taguchi.robust import RobustConfig
    from taguchi.tuning import TuningConfig

    if opts.model not in ("reduced", "two-link"):
        raise ValueError("--robust is available for --model reduced and --model two-link")
    rs = cfg.robust
    grid = opts.grid or rs.grid
    if opts.model == "two-link":
        from flexstab.two_link import TUNING_RANGES, TwoLinkNoisePlant, two_link_noise_factors

        names, ranges = factor_ranges(2, (0.0, 1.0), (0.0, 1.0), opts.factor_range)
        given = {str(sp).partition("=")[0].strip() for sp in (opts.factor_range or ())}
        ranges = tuple(r if n in given else d for n, r, d in zip(names, ranges, TUNING_RANGES))
        tkw = {"ranges": ranges, "names": names}
        noise = two_link_noise_factors(rs)
    else:
        tkw = {"kp_range": tuple(opts.kp_range) if opts.kp_range else cfg.kp_range,
               "kd_range": tuple(opts.kd_range) if opts.kd_range else cfg.kd_range}
        noise = rs.noise_factors(cfg.manipulator.tip_mass)
    target = opts.target if opts.target is not None else cfg.target
    tcfg = TuningConfig(target=target, array=opts.array, tolerance=opts.tolerance,
                        max_evaluations=opts.max_evaluations, **tkw)
    # the crossed arrays need (inner + 1) x outer runs per experiment: budget per experiment x iterations
    rcfg = RobustConfig(
        tuning=TuningConfig(target=target, array=opts.array, max_evaluations=10**6, **tkw),
        noise=noise, outer_array=rs.outer_array, sn=rs.sn, max_iterations=rs.max_iterations,
    )
    rcfg.outer()  # validates the outer array early
    omega = _omega(opts, cfg)
    if opts.model == "two-link":
        factory = TwoLinkNoisePlant(omega=omega, elements=opts.elements)
    else:
        factory = ReducedNoisePlant(omega=omega, params=cfg.manipulator, constants=opts.constants)
    n_tasks = tcfg.orthogonal_array().n_runs * len(rcfg.outer_runs())
    kind = "dask" if opts.scheduler else ("process" if opts.model == "two-link" and opts.workers != 1 else "auto")
    with make_executor(kind, max_workers=opts.workers, scheduler=opts.scheduler, n_tasks=n_tasks) as ex:
        cmp = compare_nominal_robust(factory, tcfg, rcfg, grid_points=grid, executor=ex)
    out = {"model": opts.model, "omega": omega, "period": 2 * math.pi / omega, "robust_design": True}
    out.update(cmp.to_dict())
    out["converged"] = cmp.nominal.converged
    return out


def check_tune_options(opts: TuneOptions) -> None:
    """The checks of the options alone (before the configuration and any model).

    Raises
    ------
    ValueError
        One line naming the option (as ``flexstab tune`` spells it) and the problem.
    """
    if opts.max_evaluations < 1:
        raise ValueError(f"--max-evaluations must be >= 1, got {opts.max_evaluations}")
    if opts.workers is not None and opts.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {opts.workers}")
    check_range_arg(opts.kp_range, "--kp-range")
    check_range_arg(opts.kd_range, "--kd-range")
    check_model_arg(opts.model)


def tune_gains(opts: TuneOptions, cfg: Any, *, notify: Optional[Callable[[str], None]] = None) -> dict:
    """Taguchi-tune the gains of ``opts.model`` for the configuration ``cfg``; return the JSON-ready dict
    (the ``flexstab tune --json`` object).  ``notify`` receives one line when the closed loop's largest
    multiplier belongs to a mode no drive moves (:func:`unreachable_mode`)."""
    check_tune_options(opts)
    from flexstab import plants
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    omega = _omega(opts, cfg)
    kp_range = tuple(opts.kp_range) if opts.kp_range else cfg.kp_range
    kd_range = tuple(opts.kd_range) if opts.kd_range else cfg.kd_range
    specs = opts.factor_range or None
    model_file = opts.model != "reduced"

    def tuning_config(n_drives: int, specs) -> TuningConfig:
        names, ranges = factor_ranges(n_drives, kp_range, kd_range, specs)
        return TuningConfig(target=opts.target if opts.target is not None else cfg.target, ranges=ranges,
                            names=names, array=opts.array, tolerance=opts.tolerance,
                            max_evaluations=opts.max_evaluations)

    # validate the options before the (possibly long) orbit; a model file's factor names
    # (--range) are known once its drives are
    tcfg = tuning_config(1, None if model_file else specs)
    oa = tcfg.orthogonal_array()  # validates --array early
    if opts.scheduler:
        from flexstab.executor import validate_scheduler_address

        validate_scheduler_address(opts.scheduler)
    from flexstab.executor import make_executor
    from linearize.hill_plant import HillModelPlant
    from stability.engines import floquet
    from stability.gains import MeasuredPlant
    from taguchi.direct import direct_tune

    harmonics_choice = steps_choice = None
    damping = resolve_damping(opts, cfg)
    plant = build_plant(opts.model, cfg, omega, opts.constants, opts.elements, damping)
    n_drives = len(plant.drives) if model_file else 1
    if model_file:
        tcfg = tuning_config(n_drives, specs)
        oa = tcfg.orthogonal_array()
        # the one plant rule of tune, study and chart --model: Hill where the engine rule says so (harmonics chosen at the
        # range centre, recorded), else the frozen-modal product with its steps chosen at the range centre
        unreachable = unreachable_mode(getattr(plant, "orbit", None), omega, tcfg)
        choice = plants.plant_choice_for(plant.orbit.model, plant.orbit, plant.linearization, tcfg)
        plant, harmonics_choice, steps_choice = choice.plant, choice.harmonics, choice.steps
        if unreachable is not None and notify is not None:
            notify(unreachable["message"])
    else:
        unreachable = None
    hill = model_file and isinstance(plant, HillModelPlant)
    objective = GainObjective(plant)
    kind = "dask" if opts.scheduler else (model_plant_executor(hill, opts.workers) if model_file else "auto")
    with make_executor(kind, max_workers=opts.workers, scheduler=opts.scheduler, n_tasks=oa.n_runs) as ex:
        from flexstab.progress import progress_bars

        progress = progress_bars()  # on stderr: tqdm on a terminal, one line per iteration otherwise
        if model_file:  # Hill plants: one pass (no propagator steps to refine), passes == []
            if hill and ex is not None:  # collect the workers' fallback records (HillModelPlant.fallback_runs)
                ex = FallbackRecorder(ex, plant)
            res, plant, passes = tune_model_plant(plant, tcfg, executor=ex, progress=progress)
            objective = GainObjective(plant)  # the last pass's plant (for --compare)
        else:
            res, passes = taguchi_tune(objective, tcfg, executor=ex, progress=progress), []
    out = {"model": opts.model, "omega": omega, "period": 2 * math.pi / omega}
    if model_file:
        out["drives"] = list(plant.drives)
    out.update(res.to_dict())
    if model_file:
        out["unreachable_mode"] = None if unreachable is None else {k: v for k, v in unreachable.items()
                                                                    if k != "message"}
    if passes:  # every pass's Floquet evaluations, and the step-doubling history
        out["evaluations"] = sum(p["evaluations"] for p in passes)
        out["propagator_passes"] = passes
    kp, kd = gain_pairs(res.gains, n_drives)
    out["kp"], out["kd"] = kp, kd
    gains_as_lists(out)  # the JSON typing rule: one value per drive, a list also for one drive
    if model_file and getattr(plant, "orbit", None) is not None:  # (a stand-in plant may carry none)
        out.update(plants.whole_spectrum(plant.orbit, omega, kp, kd))
    if steps_choice is not None:  # the step choice at the range centre: met tolerance / 4, or stopped at the cap
        out["propagator_choice"] = steps_choice.to_dict()
    if hill:
        # independent check: the streamed exponential-midpoint product at many steps (no Hill code)
        from flexstab.two_link import CHECK_STEPS, check_multiplier

        chk = check_multiplier(plant.linearization, plant.orbit, res.gains, steps=CHECK_STEPS,
                               harmonics=plant.harmonics)
        out["response_method"] = "hill"
        out["harmonics"] = plant.harmonics
        # whether the count met tolerance / 20 (H vs H/2 at the range centre), and that estimate (absolute)
        out["harmonics_converged"] = harmonics_choice.converged
        out["harmonics_error_estimate"] = harmonics_choice.error_estimate
        out["verified_spectral_radius"] = float(abs(chk.streamed[CHECK_STEPS[-1]]))
        out["verified_error_estimate"] = chk.magnus_error_estimate
        out["hill_error_estimate"] = chk.hill_error_estimate  # relative, H vs H/2 at the tuned gains
        out["verified_method"] = f"magnus2, {CHECK_STEPS[-1]} steps (streamed)"
        out["propagator_steps"] = plant.label_steps
        # runs whose response is not Hill's value (the frozen-modal product, refined to a quarter of the
        # tolerance; one that cannot be is a failed run): gains, method, absolute error estimate
        out["fallback_runs"] = (ex.records if isinstance(ex, FallbackRecorder) else []) + plant.fallback_runs
        from mbs_models.builtin.two_link import DEFAULT_ELEMENTS

        out["elements"] = opts.elements or DEFAULT_ELEMENTS
    elif isinstance(plant, MeasuredPlant):
        # Exudyn: re-check the dominant damped multiplier with twice the propagator steps, on the
        # unprepared plant (an independent path to P(t): gains written into K, C and interpolated)
        import dataclasses

        finer = dataclasses.replace(getattr(plant, "plant", plant), n_steps=2 * plant.n_steps)
        out["verified_spectral_radius"] = finer.spectral_measure(kp, kd)
        out["verified_error_estimate"] = None
        out["verified_method"] = f"twice the propagator steps ({finer.n_steps})"
        out["propagator_steps"] = plant.n_steps
        if opts.model in ("exudyn", "single-link"):
            out["elements"] = opts.elements or cfg.elements
        elif opts.model == "two-link":
            from mbs_models.builtin.two_link import DEFAULT_ELEMENTS

            out["elements"] = opts.elements or DEFAULT_ELEMENTS
    else:
        check = floquet(plant.with_gains(kp, kd), method="magnus").detail
        out["verified_spectral_radius"] = check.spectral_radius
        out["verified_error_estimate"] = check.error_estimate
        out["verified_method"] = f"floquet, {check.method}, {check.n_steps} steps"
    if opts.compare:
        out["direct"] = [direct_tune(objective, tcfg, m).to_dict() for m in ("nelder-mead", "differential-evolution")]
    out["damping"] = damping.to_dict()
    out.update(whole_loop_fields(opts, cfg, out, plant, kp, kd, damping))
    return out


def whole_loop_fields(opts: TuneOptions, cfg: Any, out: dict, plant: Any, kp, kd, damping) -> dict:
    """The tune JSON's honest fields: ``tuned_response`` (what the tuning drove to the target, and
    ``tuned_response_modes``, which modes it covers), ``spectral_radius`` (of the whole closed loop) with
    its ``spectral_radius_mode``, ``..._frequency_hz``, ``..._error_estimate`` (relative, that
    multiplier's own), ``spectral_radius_mesh`` (built-in models: the same at twice the elements),
    ``verdict`` / ``verdict_detail`` (:func:`stability.verdict.judge`) and ``response_note`` (words,
    when the tuned response is below the spectral radius)."""
    from flexstab.plants import MODEL_RESPONSE_MODES, mesh_dependence, response_note
    from stability.verdict import judge_floquet

    tuned = float(out["spectral_radius"])  # TaguchiResult's spectral_radius: the tuned response
    fields: dict = {"tuned_response": tuned}
    model_file = opts.model != "reduced"
    route = model_route(opts.model)
    mesh = None
    if model_file:
        fields["tuned_response_modes"] = MODEL_RESPONSE_MODES
        verdict = out.get("verdict_detail") or {}
        if route in ("single-link", "two-link"):
            from flexstab.options import resolve_model_definition

            elements = out.get("elements") or (opts.elements or cfg.elements)
            mesh = mesh_dependence(lambda e: resolve_model_definition(route, cfg, e, **damping.build_options()),
                                   out["omega"], list(kp) if isinstance(kp, list) else [kp],
                                   list(kd) if isinstance(kd, list) else [kd], int(elements))
    else:
        from stability.engines import floquet

        verdict = judge_floquet(floquet(plant.with_gains(kp, kd), method="magnus").detail).to_dict()
        fields["tuned_response_modes"] = "modes of the reduced model (hub and bending 1: all it has)"
    fields.update({"spectral_radius": verdict.get("spectral_radius"),
                   "spectral_radius_mode": verdict.get("spectral_radius_mode"),
                   "spectral_radius_frequency_hz": verdict.get("spectral_radius_frequency_hz"),
                   "spectral_radius_error_estimate": (verdict["spectral_radius_error"] / verdict["spectral_radius"]
                                                      if verdict.get("spectral_radius") else None),
                   "verdict": verdict.get("verdict"), "verdict_detail": verdict})
    if mesh is not None:
        fields["spectral_radius_mesh"] = mesh
    fields["response_note"] = response_note(tuned, fields["tuned_response_modes"], verdict, mesh)
    return fields


def check_failure(d: dict) -> Optional[str]:
    """One line saying why the tuning in ``d`` (:func:`tune_gains`) is not accepted, or ``None``.

    Not accepted: the tuning did not converge (e.g. it stopped early as unreachable or stalled, its
    message says why: :func:`taguchi.tuning.taguchi_tune`), or the independent re-check at the tuned gains
    (``verified_spectral_radius``, by ``verified_method``) lies outside ``rho_d +- tolerance``.
    """
    if not d["converged"]:
        return f"not converged: {d['message']}"
    v = d.get("verified_spectral_radius")
    how = d.get("verified_method", "the re-check")
    if v is None or not math.isfinite(v):
        return f"check failed: the independent re-check at the tuned gains ({how}) gave no value"
    if not abs(v - d["target"]) <= d["tolerance"]:
        return (f"check failed: the independent re-check at the tuned gains ({how}) gives {v:.6g}, outside "
                f"rho_d +- tolerance = {d['target']:g} +- {d['tolerance']:.3g}")
    return None
