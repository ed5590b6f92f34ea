"""``flexstab tune``: Taguchi tuning of the PD gains to a target multiplier (paper Sec. 4)."""
from __future__ import annotations

import argparse
import logging
import math
import sys
from typing import TYPE_CHECKING, Any, Optional

from flexstab.options import (add_damping_option, add_model_options, check_model_arg, check_range_arg, dump_json,
                              gain_pairs, gains_as_lists, model_route, positive_float, resolve_damping,
                              resolve_omega, result_output)

#: Names re-exported from :mod:`flexstab.plants` (the plant rule and the whole-spectrum report live
#: there), imported on first use so that parsing the command line imports no numerical package.
_PLANTS_NAMES = ("HILL_HARMONICS", "MAX_TUNING_STEPS", "MODEL_RESPONSE", "plant_choice_for",
                 "plant_for", "propagator_steps", "whole_spectrum")


def __getattr__(name: str):
    if name in _PLANTS_NAMES:
        import flexstab.plants

        return getattr(flexstab.plants, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if TYPE_CHECKING:
    from taguchi.tuning import TuningConfig

logger = logging.getLogger(__name__)

__all__ = ["register", "run", "tune_report", "unreachable_mode", "robust_report", "build_plant", "factor_ranges",
           "propagator_steps", "MAX_TUNING_STEPS", "HILL_HARMONICS", "tune_model_plant", "check_failure",
           "whole_spectrum", "MODEL_RESPONSE"]


def register(sub) -> None:
    p = sub.add_parser(
        "tune",
        help="tune the PD gains so that max|rho| reaches a target (Taguchi)",
        description="Iterative Taguchi tuning of (kp, kd) to max|rho| = rho_d (paper Eq. 34).",
    )
    p.add_argument("--model", default="reduced", metavar="MODEL",
                   help="reduced (default), exudyn (the paper's link: single-link), a built-in model file "
                        "(single-link, two-link, laval-rotor, slider-crank) or a model file PATH.py; a model with N drives tunes 2N gains (kp1, kd1, kp2, kd2, ...)")
    add_model_options(p)
    p.add_argument("--target", type=positive_float, default=None, help="rho_d (default 0.3, or from --config)")
    p.add_argument("--kp-range", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="initial range of kp (of every drive's kp); default 0 60")
    p.add_argument("--kd-range", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="initial range of kd (of every drive's kd); default 0 40")
    p.add_argument("--range", action="append", default=None, dest="factor_range", metavar="NAME=LO,HI",
                   help="initial range of one factor, e.g. kp2=0,10 (repeatable; factor names kp, kd for one "
                        "drive, kp1, kd1, kp2, ... for several); overrides --kp-range/--kd-range for it")
    p.add_argument("--array", default=None, help="orthogonal array, e.g. L9 (default), L16(4^5), L25")
    p.add_argument("--tolerance", type=positive_float, default=None, help="default 1e-3 * rho_d")
    p.add_argument("--max-evaluations", type=int, default=600, metavar="N")
    p.add_argument("--elements", type=int, default=None, help="ANCF elements (exudyn and the built-in model files)")
    add_damping_option(p)
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: auto)")
    p.add_argument("--compare", action="store_true", help="also run the direct optimisers (Nelder-Mead, DE)")
    p.add_argument("--robust", action="store_true",
                   help="robust design: gains crossed with an outer array of noise factors (payload, Omega, E; "
                        "[robust] in --config), compared with the nominal gains over a fine noise grid")
    p.add_argument("--grid", type=int, default=None, metavar="N",
                   help="--robust: points per noise factor of the worst-case grid (default [robust] grid)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


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


def robust_report(args: argparse.Namespace) -> dict:
    """``tune --robust``: nominal vs robust gains, judged over the ``[robust]`` noise grid."""
    from flexstab.executor import make_executor
    from flexstab.robust import ReducedNoisePlant, compare_nominal_robust
    from taguchi.robust import RobustConfig
    from taguchi.tuning import TuningConfig

    if args.model not in ("reduced", "two-link"):
        raise ValueError("--robust is available for --model reduced and --model two-link")
    from flexstab.config import load_config

    cfg = load_config(args.config)
    rs = cfg.robust
    grid = getattr(args, "grid", None) or rs.grid
    if args.model == "two-link":
        from flexstab.two_link import TUNING_RANGES, TwoLinkNoisePlant, two_link_noise_factors

        names, ranges = factor_ranges(2, (0.0, 1.0), (0.0, 1.0), getattr(args, "factor_range", None))
        given = {str(sp).partition("=")[0].strip() for sp in (getattr(args, "factor_range", None) or ())}
        ranges = tuple(r if n in given else d for n, r, d in zip(names, ranges, TUNING_RANGES))
        tkw = {"ranges": ranges, "names": names}
        noise = two_link_noise_factors(rs)
    else:
        tkw = {"kp_range": tuple(args.kp_range) if args.kp_range else cfg.kp_range,
               "kd_range": tuple(args.kd_range) if args.kd_range else cfg.kd_range}
        noise = rs.noise_factors(cfg.manipulator.tip_mass)
    target = args.target if args.target is not None else cfg.target
    tcfg = TuningConfig(target=target, array=args.array, tolerance=args.tolerance,
                        max_evaluations=args.max_evaluations, **tkw)
    # the crossed arrays need (inner + 1) x outer runs per experiment: budget per experiment x iterations
    rcfg = RobustConfig(
        tuning=TuningConfig(target=target, array=args.array, max_evaluations=10**6, **tkw),
        noise=noise, outer_array=rs.outer_array, sn=rs.sn, max_iterations=rs.max_iterations,
    )
    rcfg.outer()  # validates the outer array early
    omega = resolve_omega(args, cfg)
    if args.model == "two-link":
        factory = TwoLinkNoisePlant(omega=omega, elements=args.elements)
    else:
        factory = ReducedNoisePlant(omega=omega, params=cfg.manipulator, constants=args.constants)
    n_tasks = tcfg.orthogonal_array().n_runs * len(rcfg.outer_runs())
    kind = "dask" if args.scheduler else ("process" if args.model == "two-link" and args.workers != 1 else "auto")
    with make_executor(kind, max_workers=args.workers, scheduler=args.scheduler, n_tasks=n_tasks) as ex:
        cmp = compare_nominal_robust(factory, tcfg, rcfg, grid_points=grid, executor=ex)
    out = {"model": args.model, "omega": omega, "period": 2 * math.pi / omega, "robust_design": True}
    out.update(cmp.to_dict())
    out["converged"] = cmp.nominal.converged
    return out


def _print_robust(d: dict) -> None:
    nom, rob = d["nominal"], d["robust"]
    print(f"Omega = {d['omega']:.6g} rad/s, target rho_d = {d['target']:g}; robust design: inner "
          f"{rob['inner_array']} x outer {rob['outer_array']}, S/N '{rob['sn_kind']}'")
    for n in rob["noise"]:
        print(f"  noise {n['name']}: [{n['low']:g}, {n['high']:g}], nominal {n['nominal']:g}, {n['levels']} levels")
    names = rob.get("names") or ["kp", "kd"]
    print(f"{'':>8} " + "".join(f"{s:>10} " for s in names) + f"{'nominal max|rho|':>17} {'worst on grid':>14}  worst at")
    for label, row in (("nominal", nom), ("robust", rob["check"])):
        g = row["gains"]
        print(f"{label:>8} " + "".join(f"{v:10.5g} " for v in g)
              + f"{row['nominal']:17.6f} {row['worst']:14.6f}  {row['worst_noise']}")
    print(f"worst case over {d['grid_size']} grid points lowered by {d['worst_case_improvement']:.4g} "
          f"({d['worst_case_improvement_percent']:.2f} %); cost at nominal: |max|rho| - rho_d| "
          f"{'+' if d['nominal_cost'] >= 0 else ''}{d['nominal_cost']:.3g}")
    print(f"robust tuning: {rob['status']}, {rob['evaluations']} evaluations; total {d['elapsed']:.1f} s")
    for f in rob.get("failed_runs") or []:
        print(f"failed run (iteration {f['iteration']}, inner run {f['run']}, outer run {f['outer_run']}) at "
              + ", ".join(f"{s} = {v:.6g}" for s, v in zip(names, f["gains"]))
              + ", noise " + ", ".join(f"{k} = {v:.6g}" for k, v in f["noise"].items()) + f": {f['error']}")


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


class _FallbackRecorder:
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
    e.g. from :func:`propagator_steps`) is tuned
    with :class:`taguchi.tuning.GainObjective`; at the tuned gains its response with ``2 n`` propagator steps is
    compared (error estimate ``4/3 |r_n - r_2n|``: the Richardson-extrapolated 4th-order value has
    ``~ 16/15 |r_n - r_2n|``, and 4/3 bounds the error for any order >= 2, see :func:`propagator_steps`); above a quarter of
    the tolerance the tuning runs again from the initial ranges with ``2 n`` steps (the evaluation
    budget is per pass), up to :data:`MAX_TUNING_STEPS`.

    Returns
    -------
    (TaguchiResult, plant, passes)
        The last pass's result, the plant it used and one dict per pass (``propagator_steps``,
        ``evaluations``, ``spectral_radius``, ``check_2n``, ``converged``).
    """
    import dataclasses

    from stability.refine import pair_estimate
    from taguchi.tuning import GainObjective, recentre, taguchi_tune

    MAX_TUNING_STEPS = sys.modules[__name__].MAX_TUNING_STEPS  # the re-export (patchable in tests)

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


def tune_report(args: argparse.Namespace) -> dict:
    """Run the tuning described by ``args``; return the JSON-ready dict."""
    if args.max_evaluations < 1:
        raise ValueError(f"--max-evaluations must be >= 1, got {args.max_evaluations}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    check_range_arg(args.kp_range, "--kp-range")
    check_range_arg(args.kd_range, "--kd-range")
    check_model_arg(args.model)
    from flexstab.config import load_config
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    cfg = load_config(args.config)
    omega = resolve_omega(args, cfg)
    kp_range = tuple(args.kp_range) if args.kp_range else cfg.kp_range
    kd_range = tuple(args.kd_range) if args.kd_range else cfg.kd_range
    specs = getattr(args, "factor_range", None)
    model_file = args.model != "reduced"

    def tuning_config(n_drives: int, specs) -> TuningConfig:
        names, ranges = factor_ranges(n_drives, kp_range, kd_range, specs)
        return TuningConfig(target=args.target if args.target is not None else cfg.target, ranges=ranges,
                            names=names, array=args.array, tolerance=args.tolerance,
                            max_evaluations=args.max_evaluations)

    # validate the options before the (possibly long) orbit; a model file's factor names
    # (--range) are known once its drives are
    tcfg = tuning_config(1, None if model_file else specs)
    oa = tcfg.orthogonal_array()  # validates --array early
    if args.scheduler:
        from flexstab.executor import validate_scheduler_address

        validate_scheduler_address(args.scheduler)
        if model_file:
            raise ValueError("--scheduler: model-file plants run in-process (serial) only")
    from flexstab.executor import make_executor
    from linearize.hill_plant import HillModelPlant
    from stability.engines import floquet
    from stability.gains import MeasuredPlant
    from taguchi.direct import direct_tune

    harmonics_choice = steps_choice = None
    damping = resolve_damping(args, cfg)
    plant = build_plant(args.model, cfg, omega, args.constants, args.elements, damping)
    n_drives = len(plant.drives) if model_file else 1
    if model_file:
        tcfg = tuning_config(n_drives, specs)
        oa = tcfg.orthogonal_array()
        # the one plant rule of tune, study and chart --model: Hill where the engine rule says so (harmonics chosen at the
        # range centre, recorded), else the frozen-modal product with its steps chosen at the range centre
        unreachable = unreachable_mode(getattr(plant, "orbit", None), omega, tcfg)
        choice = sys.modules[__name__].plant_choice_for(plant.orbit.model, plant.orbit, plant.linearization, tcfg)
        plant, harmonics_choice, steps_choice = choice.plant, choice.harmonics, choice.steps
        if unreachable is not None:
            print(f"flexstab tune: {unreachable['message']}", file=sys.stderr, flush=True)
    else:
        unreachable = None
    hill = model_file and isinstance(plant, HillModelPlant)
    objective = GainObjective(plant)
    kind = "dask" if args.scheduler else "auto"
    if model_file:
        if args.scheduler:
            raise ValueError("--scheduler: model-file plants run in-process (serial) only")
        # the plant holds a model loaded from a file: not picklable -- except the built-in ones
        kind = "process" if hill and args.workers != 1 else "serial"
    with make_executor(kind, max_workers=args.workers, scheduler=args.scheduler, n_tasks=oa.n_runs) as ex:
        from flexstab.progress import progress_bars

        progress = progress_bars()  # on stderr: tqdm on a terminal, one line per iteration otherwise
        if model_file:  # Hill plants: one pass (no propagator steps to refine), passes == []
            if hill and ex is not None:  # collect the workers' fallback records (HillModelPlant.fallback_runs)
                ex = _FallbackRecorder(ex, plant)
            res, plant, passes = tune_model_plant(plant, tcfg, executor=ex, progress=progress)
            objective = GainObjective(plant)  # the last pass's plant (for --compare)
        else:
            res, passes = taguchi_tune(objective, tcfg, executor=ex, progress=progress), []
    out = {"model": args.model, "omega": omega, "period": 2 * math.pi / omega}
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
        out.update(sys.modules[__name__].whole_spectrum(plant.orbit, omega, kp, kd))
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
        out["fallback_runs"] = (ex.records if isinstance(ex, _FallbackRecorder) else []) + plant.fallback_runs
        from mbs_models.builtin.two_link import DEFAULT_ELEMENTS

        out["elements"] = args.elements or DEFAULT_ELEMENTS
    elif isinstance(plant, MeasuredPlant):
        # Exudyn: re-check the dominant damped multiplier with twice the propagator steps, on the
        # unprepared plant (an independent path to P(t): gains written into K, C and interpolated)
        import dataclasses

        finer = dataclasses.replace(getattr(plant, "plant", plant), n_steps=2 * plant.n_steps)
        out["verified_spectral_radius"] = finer.spectral_measure(kp, kd)
        out["verified_error_estimate"] = None
        out["verified_method"] = f"twice the propagator steps ({finer.n_steps})"
        out["propagator_steps"] = plant.n_steps
        if args.model in ("exudyn", "single-link"):
            out["elements"] = args.elements or cfg.elements
        elif args.model == "two-link":
            from mbs_models.builtin.two_link import DEFAULT_ELEMENTS

            out["elements"] = args.elements or DEFAULT_ELEMENTS
    else:
        check = floquet(plant.with_gains(kp, kd), method="magnus").detail
        out["verified_spectral_radius"] = check.spectral_radius
        out["verified_error_estimate"] = check.error_estimate
        out["verified_method"] = f"floquet, {check.method}, {check.n_steps} steps"
    if args.compare:
        out["direct"] = [direct_tune(objective, tcfg, m).to_dict() for m in ("nelder-mead", "differential-evolution")]
    out["damping"] = damping.to_dict()
    out.update(whole_loop_fields(args, cfg, out, plant, kp, kd, damping))
    return out


def whole_loop_fields(args: argparse.Namespace, cfg, out: dict, plant: Any, kp, kd, damping) -> dict:
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
    model_file = args.model != "reduced"
    route = model_route(args.model)
    mesh = None
    if model_file:
        fields["tuned_response_modes"] = MODEL_RESPONSE_MODES
        verdict = out.get("verdict_detail") or {}
        if route in ("single-link", "two-link"):
            from flexstab.options import resolve_model_definition

            elements = out.get("elements") or (args.elements or cfg.elements)
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


def _response_name(d: dict) -> str:
    return "tuned response, dominant |rho| (drive modes, bending 1)" if d.get("response") else "tuned response, max|rho|"


def run(args: argparse.Namespace) -> int:
    if getattr(args, "robust", False):
        from flexstab.progress import progress_log

        with progress_log("flexstab.robust", "tune"), progress_log("taguchi.robust", "tune"):  # stages, on stderr
            d = robust_report(args)
        with result_output(args):
            if args.json:
                dump_json(d, sys.stdout)
            else:
                _print_robust(d)
        return 0 if d["converged"] else 1
    d = tune_report(args)
    failure = check_failure(d)
    if failure:
        print(f"flexstab tune: {failure}", file=sys.stderr)
    rc = 1 if failure else 0
    with result_output(args):
        return _print_tune(args, d, rc)


def _print_tune(args: argparse.Namespace, d: dict, rc: int) -> int:
    """Print the tuning result ``d`` (a table, or one JSON object with ``--json``); return ``rc``."""
    if args.json:
        dump_json(d, sys.stdout)
        return rc
    print(f"Omega = {d['omega']:.6g} rad/s, target rho_d = {d['target']:g}, array {d['array']}")
    print(f"status: {d['status']} -- {d['message']}")
    names = d["names"]
    if len(names) == 2:
        gains = f"kp = {d['gains'][0]:.6g}   kd = {d['gains'][1]:.6g}"
        if d.get("drives"):
            gains = f"drive {d['drives'][0]}: {gains}"
        print(f"{gains}   {_response_name(d)} = {d.get('tuned_response', d['spectral_radius']):.6g} "
              f"(re-checked: {d['verified_spectral_radius']:.6g})")
    else:
        for j, drive in enumerate(d.get("drives") or [f"{j + 1}" for j in range(len(names) // 2)]):
            print(f"drive {drive}: {names[2 * j]} = {d['gains'][2 * j]:.6g}   "
                  f"{names[2 * j + 1]} = {d['gains'][2 * j + 1]:.6g}")
        print(f"{_response_name(d)} = {d.get('tuned_response', d['spectral_radius']):.6g} "
              f"(re-checked: {d['verified_spectral_radius']:.6g})")
    if d.get("spectral_radius") is not None and d.get("verdict_detail"):
        freq = d.get("spectral_radius_frequency_hz")
        err = d.get("spectral_radius_error_estimate")
        mode = d.get("spectral_radius_mode")
        print(f"whole loop: spectral radius {d['spectral_radius']:.6g}"
              + (f" ({mode}" + (f", {freq:.4g} Hz" if freq else "") + ")" if mode else "")
              + (f", relative error estimate {err:.1e}" if err is not None else ""))
        for m in d.get("spectral_radius_mesh") or []:
            print(f"  at {m['elements']} elements: {m['spectral_radius']:.6g} ({m['mode']}) -> {m['verdict']}")
        print(f"verdict: {d['verdict_detail']['message']}")
        if d.get("response_note"):
            print(f"note: {d['response_note']}")
    print(f"{d['evaluations']} Floquet evaluations in {len(d['iterations'])} iterations, {d['elapsed']:.2f} s")
    for f in d.get("failed_runs") or []:
        print(f"failed run (iteration {f['iteration']}, run {f['run']}) at "
              + ", ".join(f"{s} = {v:.6g}" for s, v in zip(names, f["gains"])) + f": {f['error']}")
    if d.get("fallback_runs"):
        print(f"{len(d['fallback_runs'])} runs used the frozen-modal product instead of Hill's value (refined to "
              f"tolerance / 4; see fallback_runs)")
    pc = d.get("propagator_choice")
    if pc and not pc["converged"]:
        print(f"warning: {pc['n_steps']} propagator steps (the cap) did not meet tolerance / 4 at the range centre "
              f"(estimate {pc['error_estimate']:.2e})")
    if d.get("harmonics_converged") is False:
        print(f"warning: Hill's harmonics ({d['harmonics']}) did not meet tolerance / 20 at the range centre "
              f"(estimate {d['harmonics_error_estimate']:.2e})")
    if len(names) == 2:
        print("\n iter   kp range              kd range              best kp     best kd     max|rho|")
        for it in d["iterations"]:
            inc = it["incumbent"]
            r0, r1 = it[f"{names[0]}_range"], it[f"{names[1]}_range"]
            print(f" {it['index']:>4}   [{r0[0]:8.4g}, {r0[1]:8.4g}]  [{r1[0]:8.4g}, {r1[1]:8.4g}]  "
                  f"{inc[names[0]]:10.5g}  {inc[names[1]]:10.5g}  {inc['spectral_radius']:.6g}")
    else:
        print("\n iter  " + "".join(f"{s + ' range':>22}" for s in names) + "   max|rho| (best: "
              + ", ".join(names) + ")")
        for it in d["iterations"]:
            inc = it["incumbent"]
            rng = "".join(f"  [{it[s + '_range'][0]:8.4g}, {it[s + '_range'][1]:8.4g}]" for s in names)
            print(f" {it['index']:>4}  {rng}   {inc['spectral_radius']:.6g} ("
                  + ", ".join(f"{inc[s]:.5g}" for s in names) + ")")
    last = d["iterations"][-1] if d["iterations"] else None
    if last:
        rt = last["response_table"]
        print(f"\nresponse table of the last experiment (mean S/N in dB per level; levels 1..{len(rt['level_means'][0])}):")
        print(f"{'level':>7}" + "".join(f"{s:>12}" for s in names))
        for k in range(len(rt["level_means"][0])):
            print(f"{k + 1:>7}" + "".join(f"{m[k]:12.3f}" for m in rt["level_means"]))
        print(f"{'delta':>7}" + "".join(f"{v:12.3f}" for v in rt["delta"]))
        print(f"{'rank':>7}" + "".join(f"{v:12d}" for v in rt["rank"]))
        c = last["contribution_percent"]
        print("contribution (ANOVA on S/N): " + ", ".join(f"{s} {v:.1f} %" for s, v in zip(names, c))
              + f", error {last['error_contribution_percent']:.1f} %")
        print(f"predicted S/N at the best levels {last['predicted_sn']:.2f} dB, "
              f"confirmation run {last['confirmation']['sn']:.2f} dB")
    for dr in d.get("direct", []):
        gains = ", ".join(f"{s} = {g:.6g}" for s, g in zip(dr["names"], dr["gains"]))
        print(f"direct {dr['method']}: {dr['status']}, {dr['evaluations']} evaluations, {dr['elapsed']:.2f} s, {gains}")
    return rc


def check_failure(d: dict) -> Optional[str]:
    """One line saying why the tuning in ``d`` (:func:`tune_report`) is not accepted, or ``None``.

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
