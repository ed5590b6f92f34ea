"""Floquet multipliers measured from nonlinear Exudyn runs: the library half of ``flexstab validate``.

:func:`validate_multipliers` measures the one-period map of the nonlinear closed loop (feed-forward + PD,
started from the periodic orbit perturbed along the predicted Floquet vectors) with generalised-alpha at
steps ``h, h/2, h/4`` and compares its eigenvalues with the predicted multipliers in modulus and phase
within the measurement's error bar (:func:`validation.multipliers.validate_model_multipliers`).  For a
model file it can also measure the whole one-period map from random constraint-consistent perturbations
(:mod:`validation.full_map`); a resolved slow multiplier without a predicted partner is then a failed check.

Two routes, by :attr:`ValidateOptions.model`:

* ``exudyn``: the paper's link, the built-in model file ``single-link`` with the configuration's
  manipulator (default 4 elements), the reduced model's multipliers as an alternative prediction, and
  the gains of :func:`resolve_gains` when none are given;
* a model file ``PATH.py`` or a built-in model name: the model's own defaults, ``Omega`` 2pi unless
  given, gains 0 for every drive unless given (no configuration applies).

:func:`validate_multipliers` returns a :class:`ValidateResult`: the JSON object of
``flexstab validate --json`` and the measurement itself (for the complex-plane figure).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Optional

from flexstab.options import check_model_arg, gains_as_lists, is_model_file

logger = logging.getLogger(__name__)

__all__ = ["ValidateOptions", "ValidateResult", "validate_multipliers", "check_validate_options", "resolve_gains",
           "DEFAULT_ELEMENTS", "DEFAULT_FULL_MAP_WORKERS", "MAX_REFINEMENTS", "CONFIG_FOR_MODEL_FILE"]

#: ANCF elements of the paper's link (``model="exudyn"``) unless given.
DEFAULT_ELEMENTS = 4
#: Worker processes of the full-map runs unless given (1: serial).
DEFAULT_FULL_MAP_WORKERS = 2
#: Most step halvings (the step levels are ``h, h/2, ..., h / 2**refinements``).
MAX_REFINEMENTS = 4
#: Why a configuration is refused for a model file (it describes the built-in manipulator).
CONFIG_FOR_MODEL_FILE = "--config describes the built-in manipulator; it does not apply to a model file"


@dataclass(frozen=True)
class ValidateOptions:
    """What :func:`validate_multipliers` measures (``None``: the route's default, see the module docstring).

    Attributes
    ----------
    model : str
        ``exudyn`` (the paper's link), a built-in model file name or a model file ``PATH.py``.
    omega : float, optional
        Frequency of the periodic motion (rad/s); default the configuration's (``exudyn``), else 2pi.
    kp, kd : tuple of float, optional
        Gains, one value or one per drive (``exudyn``: one).  If both are ``None``: :func:`resolve_gains`
        (``exudyn``) or 0 for every drive; if one is given, the other is 0.
    gains_source : str
        Where given gains come from (the ``gains_source`` of the report).
    elements : int, optional
        ANCF elements (``exudyn``: default :data:`DEFAULT_ELEMENTS`; built-in model files: passed to their
        build; refused for a model file ``PATH.py``).
    samples : int, optional
        Orbit / linearisation samples per period (even, >= 4; default
        :data:`validation.multipliers.MODEL_SAMPLES`).
    step : float, optional
        Coarsest generalised-alpha step in s, below the period (default
        :func:`validation.multipliers.suggested_step`).
    spectral_radius : float
        Generalised-alpha ``rho_inf`` in [0, 1] (1: no numerical damping).
    refinements : int
        Step halvings, 0 to :data:`MAX_REFINEMENTS` (2: ``h, h/2, h/4``, the least for a verdict).
    amplitude : float, optional
        Perturbation energy as a hub-velocity kick in rad/s (> 0).
    compare : int
        Number of multipliers compared (>= 1; pairs kept whole).
    growth_periods : int, optional
        Periods of the multi-period growth run (``exudyn``: default 3 at zero gains, else 0; model files 0).
    predict_reference : str
        Reference motion of the prediction: ``periodic`` (the only one available).
    full_map : bool
        Model files: also measure the whole one-period map (:func:`validation.full_map.measure_model_full_map`).
    full_map_step : float, optional
        Coarsest step of the full-map runs in s (default: the same rule as ``step``).
    workers : int, optional
        Worker processes of the full-map runs (default :data:`DEFAULT_FULL_MAP_WORKERS`; 1: serial).
    """

    model: str = "exudyn"
    omega: Optional[float] = None
    kp: Optional[tuple] = None
    kd: Optional[tuple] = None
    gains_source: str = "command line"
    elements: Optional[int] = None
    samples: Optional[int] = None
    step: Optional[float] = None
    spectral_radius: float = 1.0
    refinements: int = 2
    amplitude: Optional[float] = None
    compare: int = 2
    growth_periods: Optional[int] = None
    predict_reference: str = "periodic"
    full_map: bool = False
    full_map_step: Optional[float] = None
    workers: Optional[int] = None


@dataclass(frozen=True)
class ValidateResult:
    """Outcome of :func:`validate_multipliers`.

    Attributes
    ----------
    report : dict
        The JSON-ready object of ``flexstab validate --json`` (docs/cli.md lists its keys): the
        measurement's :meth:`~validation.multipliers.MultiplierValidation.to_dict` with ``model``,
        ``elements``, ``gains_source`` and, with ``full_map``, the ``full_map`` block.
    measurement : validation.multipliers.MultiplierValidation
        The measurement (for :func:`validation.plots.plot_multiplier_plane`).
    options : ValidateOptions
        The options that produced it.
    """

    report: dict
    measurement: Any
    options: ValidateOptions

    @property
    def agrees(self) -> bool:
        """Whether the measurement confirms the prediction (the report's ``agrees``)."""
        return bool(self.report.get("agrees"))

    def to_dict(self) -> dict:
        """The JSON-ready report (:attr:`report`)."""
        return self.report


def _at_least(flag: str, value, minimum, *, strict: bool = False) -> None:
    if value is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"--{flag} must be {'>' if strict else '>='} {minimum:g}, got {value:g}")


def check_validate_options(opts: ValidateOptions) -> None:
    """The checks of the options alone (before the configuration, any model and any numerical import).

    Raises
    ------
    ValueError
        One line naming the option (as ``flexstab validate`` spells it) and the problem.
    """
    exudyn = opts.model == "exudyn"
    if not exudyn:
        if opts.predict_reference != "periodic":
            raise ValueError("--predict-reference accepts only 'periodic': the prediction is the linearisation "
                             "about the periodic orbit")
        check_model_arg(opts.model)
        if opts.elements is not None and is_model_file(opts.model):
            raise ValueError("--elements applies to the built-in models only (a model file sets its own mesh)")
    elif opts.full_map:
        raise ValueError("--full-map applies to model files (e.g. --model single-link), not to --model exudyn")
    _at_least("omega", opts.omega, 0.0, strict=True)
    for flag, gains in (("kp", opts.kp), ("kd", opts.kd)):
        for g in gains or ():
            _at_least(flag, g, 0.0)
        if exudyn and gains is not None and len(gains) != 1:
            raise ValueError(f"--{flag}: the built-in single link has one drive (hub), got {len(gains)} values")
    _at_least("elements", opts.elements, 1)
    _at_least("samples", opts.samples, 4)
    if opts.samples is not None and opts.samples % 2:
        raise ValueError(f"--samples must be even, got {opts.samples}")
    _at_least("step", opts.step, 0.0, strict=True)
    _at_least("refinements", opts.refinements, 0)
    if opts.refinements > MAX_REFINEMENTS:
        raise ValueError(f"--refinements must be <= {MAX_REFINEMENTS}, got {opts.refinements}")
    _at_least("amplitude", opts.amplitude, 0.0, strict=True)
    _at_least("compare", opts.compare, 1)
    _at_least("growth-periods", opts.growth_periods, 0)
    _at_least("spectral-radius", opts.spectral_radius, 0.0)
    if opts.spectral_radius > 1.0:
        raise ValueError(f"--spectral-radius must be in [0, 1], got {opts.spectral_radius:g}")
    _at_least("full-map-step", opts.full_map_step, 0.0, strict=True)
    _at_least("workers", opts.workers, 1)
    if exudyn and opts.predict_reference != "periodic":
        raise ValueError("--predict-reference accepts only 'periodic': the prediction is the linearisation "
                         "about the periodic orbit (the rigid reference's distance is in docs/validation.md)")


def _below_period(flag: str, step: Optional[float], period: float) -> None:
    if step is not None and step >= period:
        raise ValueError(f"--{flag} must be smaller than the period T = {period:.6g} s, got {step:g}")


def resolve_gains(omega: float, kp: Optional[float], kd: Optional[float], cfg=None) -> tuple[float, float, str]:
    """Gains of the paper's link and where they come from.

    If neither ``kp`` nor ``kd`` is given: the paper's printed Table 3 gains for the paper's manipulator at
    one of the paper's Omegas (2pi, 4pi, 6pi, 8pi), otherwise the gains Taguchi tunes on the reduced model
    of the configured manipulator at ``omega`` to the configured target (the printed gains belong to the
    paper's link only).  If one is given, the other is 0.

    Parameters
    ----------
    omega : float
    kp, kd : float, optional
    cfg : flexstab.config.StudyConfig, optional
        Decides whether the printed gains apply and gives the tuning's target and ranges (default the
        paper's manipulator).

    Returns
    -------
    (kp, kd, source)
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


def _check_config(opts: ValidateOptions, growth_periods: int) -> Any:
    """The :class:`validation.multipliers.MultiplierCheckConfig` of ``opts``."""
    from validation.multipliers import MultiplierCheckConfig

    return MultiplierCheckConfig(compare=opts.compare, step=opts.step, refinements=opts.refinements,
                                 amplitude=opts.amplitude, growth_periods=growth_periods,
                                 spectral_radius=opts.spectral_radius)


def validate_multipliers(opts: ValidateOptions, cfg: Any = None) -> ValidateResult:
    """Measure the multipliers of ``opts`` and compare them with the prediction (see the module docstring).

    Parameters
    ----------
    opts : ValidateOptions
    cfg : flexstab.config.StudyConfig, optional
        ``model="exudyn"``: the manipulator, Omega, target and ranges (default the paper's); refused for
        a model file.

    Returns
    -------
    ValidateResult

    Raises
    ------
    ValueError
        Bad options (before any numerical work), or a configuration given for a model file.
    """
    check_validate_options(opts)
    if opts.model != "exudyn":
        if cfg is not None:
            raise ValueError(CONFIG_FOR_MODEL_FILE)
        return _model_file_validation(opts)
    from flexstab.config import StudyConfig

    cfg = cfg if cfg is not None else StudyConfig()
    omega = cfg.omega if opts.omega is None else opts.omega
    _below_period("step", opts.step, 2 * math.pi / omega)
    from flexstab.options import resolve_model_definition
    from mbs_models.reduced import ReducedModel
    from stability import floquet
    from validation.multipliers import MODEL_SAMPLES, prediction_from_multipliers, validate_model_multipliers

    given = opts.kp is not None or opts.kd is not None
    kp, kd, source = resolve_gains(omega, opts.kp[0] if opts.kp else None, opts.kd[0] if opts.kd else None, cfg)
    if given:
        source = opts.gains_source
    growth = opts.growth_periods
    if growth is None:
        growth = 3 if (kp == 0.0 and kd == 0.0) else 0
    config = _check_config(opts, growth)
    elements = DEFAULT_ELEMENTS if opts.elements is None else opts.elements
    # the paper's link is the built-in model file single-link with the configured manipulator
    definition, options = resolve_model_definition(opts.model, cfg, elements)
    reduced = floquet(ReducedModel(omega=omega, kp=kp, kd=kd, params=cfg.manipulator))
    logger.info("validating the paper's link at Omega = %.6g rad/s, kp = %.6g, kd = %.6g (%s)", omega, kp, kd, source)
    res = validate_model_multipliers(definition, omega, kp=kp, kd=kd,
                                     samples=MODEL_SAMPLES if opts.samples is None else opts.samples, config=config,
                                     alternatives=[prediction_from_multipliers("reduced model", reduced.multipliers)],
                                     **options)
    d = res.to_dict()
    d["model"] = opts.model
    d["elements"] = elements
    d["gains_source"] = source
    return ValidateResult(gains_as_lists(d), res, opts)


def _model_file_validation(opts: ValidateOptions) -> ValidateResult:
    """A model file ``PATH.py`` or a built-in model name: the generic route."""
    omega = opts.omega if opts.omega is not None else 2 * math.pi
    period = 2 * math.pi / omega
    _below_period("step", opts.step, period)
    _below_period("full-map-step", opts.full_map_step, period)
    from mbs_models.model_file import resolve_model
    from validation.multipliers import MODEL_SAMPLES, validate_model_multipliers

    options = {} if opts.elements is None else {"elements": opts.elements}
    definition = resolve_model(opts.model, **options)
    samples = MODEL_SAMPLES if opts.samples is None else opts.samples
    kp = list(opts.kp) if opts.kp else 0.0
    kd = list(opts.kd) if opts.kd else 0.0
    logger.info("validating %s at Omega = %.6g rad/s", definition.name, omega)
    res = validate_model_multipliers(definition, omega, kp=kp, kd=kd, samples=samples, config=_check_config(opts, opts.growth_periods or 0))
    d = res.to_dict()
    d["gains_source"] = opts.gains_source if (opts.kp or opts.kd) else "none given (0 for every drive)"
    d.setdefault("elements", definition.options.get("elements"))
    if opts.full_map:
        workers = DEFAULT_FULL_MAP_WORKERS if opts.workers is None else opts.workers
        d["full_map"] = _full_map(opts.model, options, omega, kp, kd, samples, opts.full_map_step, opts.refinements,
                                  opts.amplitude, workers)
    return ValidateResult(gains_as_lists(d), res, opts)


def _full_map(model, options, omega, kp, kd, samples, step, refinements, amplitude, workers) -> dict:
    """The ``full_map`` block: :func:`validation.full_map.measure_model_full_map` against the linearisation."""
    from flexstab.executor import make_executor
    from linearize.analysis import analyze
    from mbs_models.console import exudyn_console
    from validation.full_map import FullMapConfig, full_map_report, measure_model_full_map

    cfg = FullMapConfig(step=step, refinements=max(refinements, 2), amplitude=amplitude)
    with make_executor("process" if workers > 1 else "serial", max_workers=workers) as ex:
        result, runner = measure_model_full_map(model, omega, kp, kd, samples=samples, config=cfg,
                                                executor=None if workers == 1 else ex, chunks=workers, **options)
    with exudyn_console(True):
        analysis = analyze(runner.definition, omega, kp=kp, kd=kd, samples=samples, orbit=runner.orbit)
    return full_map_report(result, analysis)
