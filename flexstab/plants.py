"""The tuning plant of a model file: one rule for ``tune --model``, ``study --model`` and ``chart --model``.

A model file's response (:data:`MODEL_RESPONSE`) is the modulus of the dominant labelled
multiplier (drive modes and the first bending mode).  How it is evaluated depends on the model:

* a model whose linearisation the engine rule :func:`stability.engines.rule.choose_method` gives to
  Hill's method (stiff modes whose frozen frequencies change so much over the period that the
  frozen-modal product would need more than its step budget for the tuning tolerance -- the
  two-link arm, whose elbow couples the links' axial and bending modes differently along the
  period): :class:`linearize.hill_plant.HillModelPlant`, its harmonic count chosen once at the
  centre of the tuning ranges (:func:`hill_plant`);
* every other model: the Richardson-extrapolated exponential midpoint in the frozen-modal frame,
  :class:`linearize.analysis.ModelPlant`, its step count chosen once at the centre of the tuning
  ranges (:func:`propagator_steps`) unless given.

:func:`plant_for` applies that rule; the three commands call it with the same tuning
configuration, so at the same gains they evaluate the same quantity by the same method and
discretisation.  ``tune``/``study`` may afterwards double a :class:`ModelPlant`'s steps when the
step-doubling check at the tuned gains asks for it (:func:`flexstab.tuning.tune_model_plant`).

:func:`whole_spectrum` reports, beside the tuned response, the spectral radius of the whole
linearisation at the tuned gains (``tune --model`` and the study's two-link section).
"""
from __future__ import annotations

import dataclasses
import logging
import warnings
from typing import Any, Optional, Sequence

from linearize.analysis import ModelPlant
from linearize.hill_plant import HarmonicsChoice, HillModelPlant, select_harmonics
from linearize.periodic_orbit import PeriodicOrbit
from linearize.system import LinearizedPeriodicSystem
from stability.engines.rule import choose_method, system_properties
from stability.gains import Gains, MeasuredPlant
from stability.refine import double_until
from taguchi.tuning import TuningConfig

__all__ = ["HILL_HARMONICS", "MODEL_RESPONSE", "MODEL_RESPONSE_MODES", "MAX_TUNING_STEPS", "PlantChoice",
           "relative_tolerance", "response_method", "uses_hill", "hill_plant", "hill_choice", "StepsChoice",
           "propagator_choice", "propagator_steps", "plant_for", "plant_choice_for", "whole_spectrum",
           "mesh_dependence", "response_note"]

logger = logging.getLogger(__name__)

#: Hill harmonic counts tried (fewest first) for a model evaluated by Hill's method; see
#: :func:`linearize.hill_plant.select_harmonics`.
HILL_HARMONICS = (8, 12, 16, 24, 32)

#: Upper bound of the propagator sub-intervals chosen by :func:`propagator_steps`.
MAX_TUNING_STEPS = 4096

#: What a model file's tuning response is (the JSON ``response`` field): the plant's labelled dominant multiplier.
MODEL_RESPONSE = "dominant multiplier of the drive modes and bending 1 (the tuned quantity)"
#: The modes :data:`MODEL_RESPONSE` covers, in a sentence ("the ... decay at 0.30 per period").
MODEL_RESPONSE_MODES = "drive modes and bending 1"

def relative_tolerance(config: Optional[TuningConfig]) -> float:
    """The relative accuracy a tuning response needs: a quarter of the tuning tolerance over rho_d (the
    fraction the step and harmonic choices meet), ``2.5e-4`` for the default configuration."""
    config = config if config is not None else TuningConfig()
    return 0.25 * config.effective_tolerance / abs(config.target)


def response_method(lin: LinearizedPeriodicSystem, config: Optional[TuningConfig]) -> str:
    """The engine rule (:func:`stability.engines.rule.choose_method`) applied to the linearisation at gains 0
    with the tuning's relative accuracy: ``"hill"``, ``"modal"`` or ``"magnus"`` (the last two are both
    evaluated by the time-stepping :class:`ModelPlant`)."""
    return choose_method(system_properties(lin), rtol=relative_tolerance(config))


def uses_hill(lin: LinearizedPeriodicSystem, config: Optional[TuningConfig]) -> bool:
    """Whether a model's tuning response is Hill's: it has drives and :func:`response_method` says so."""
    return bool(lin.B is not None and lin.B.shape[-1]) and response_method(lin, config) == "hill"


def _centre(config: TuningConfig) -> tuple[list, list]:
    """``(kp, kd)`` per drive at the centre of the initial ranges of ``config``."""
    centre = Gains.from_interleaved([0.5 * (lo + hi) for lo, hi in config.factor_ranges])
    return list(centre.kp), list(centre.kd)


def hill_choice(lin: LinearizedPeriodicSystem, orbit: PeriodicOrbit, config: TuningConfig) -> HarmonicsChoice:
    """Hill's harmonic count decided once, at the centre of the tuning ranges
    (:func:`linearize.hill_plant.select_harmonics` over :data:`HILL_HARMONICS`, H vs H/2 below
    ``tolerance / 20``; warns and says ``converged=False`` when no count meets it)."""
    kp, kd = _centre(config)
    return select_harmonics(HillModelPlant(lin, orbit), kp, kd, config.effective_tolerance, HILL_HARMONICS)


def hill_plant(lin: LinearizedPeriodicSystem, orbit: PeriodicOrbit, config: TuningConfig, *,
               harmonics: Optional[int] = None) -> HillModelPlant:
    """:class:`HillModelPlant` with its harmonics from :func:`hill_choice`, or ``harmonics``."""
    if harmonics is not None:
        return HillModelPlant(lin, orbit).replace(harmonics=harmonics, tolerance=config.effective_tolerance)
    return hill_choice(lin, orbit, config).plant


@dataclasses.dataclass(frozen=True)
class StepsChoice:
    """Outcome of :func:`propagator_choice`.

    Attributes
    ----------
    plant : ModelPlant
        The plant with the chosen steps (``MAX_TUNING_STEPS`` or the last count below it when
        none met the criterion).
    n_steps : int
    converged : bool
        Whether ``error_estimate <= tolerance / 4`` at ``n_steps``.
    error_estimate : float
        ``4/3 |r_m - r_2m|`` of the last pair compared: ``m = n_steps`` when converged; when the cap
        stopped the doubling, ``m = n_steps / 2`` (it bounds the error of ``r_m``, so over-states
        that of the returned, finer ``n_steps``); NaN when no pair fitted under the cap.
    tolerance : float
        The tuning tolerance it was chosen for.
    """

    plant: Any
    n_steps: int
    converged: bool
    error_estimate: float
    tolerance: float

    def to_dict(self) -> dict:
        """JSON-ready (without the plant)."""
        return {"n_steps": self.n_steps, "converged": self.converged, "error_estimate": self.error_estimate,
                "tolerance": self.tolerance}


def propagator_choice(plant: Any, tcfg: TuningConfig) -> StepsChoice:
    """Enough propagator steps for the tuning tolerance (model-file plants), and how well they meet it.

    The response is evaluated at the centre of the initial ranges with ``n`` and
    ``2n`` propagator steps.  For a :class:`~linearize.analysis.ModelPlant` the value is the
    Richardson-extrapolated exponential midpoint (4th order: the error of ``n`` steps is
    ``~ 16/15 |r_n - r_2n|`` asymptotically); the estimate used is ``4/3 |r_n - r_2n|``, which
    bounds the error for any observed order ``p >= 2`` (the factor ``2^p / (2^p - 1)`` falls
    with ``p``), i.e. also before the extrapolated value reaches its 4th order.  ``n`` is
    doubled from ``plant.n_steps`` until that estimate is below a quarter of the tolerance,
    or ``MAX_TUNING_STEPS``: then the choice says ``converged=False`` with the estimate reached,
    and a ``RuntimeWarning`` is issued (as :func:`linearize.hill_plant.select_harmonics` does).
    """
    kp, kd = _centre(tcfg)
    tol = tcfg.effective_tolerance
    ref = double_until(lambda n: dataclasses.replace(plant, n_steps=n).spectral_measure(kp, kd), int(plant.n_steps),
                       MAX_TUNING_STEPS, 0.25 * tol)
    n, estimate, converged = ref.n, ref.estimate, ref.converged
    if not converged:
        msg = (f"propagator steps: the step-doubling estimate {estimate:.2e} at the centre of the gain ranges "
               f"(kp={kp} kd={kd}) is above tolerance / 4 = {0.25 * tol:.2e} at MAX_TUNING_STEPS = "
               f"{MAX_TUNING_STEPS}; using {n} steps")
        logger.warning(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
    return StepsChoice(plant=dataclasses.replace(plant, n_steps=n), n_steps=n, converged=converged,
                       error_estimate=float(estimate), tolerance=tol)


def propagator_steps(plant: Any, tcfg: TuningConfig) -> Any:
    """``propagator_choice(plant, tcfg).plant``: ``plant`` with enough propagator steps for the tuning
    tolerance (warns when ``MAX_TUNING_STEPS`` stopped the doubling first)."""
    return propagator_choice(plant, tcfg).plant


@dataclasses.dataclass(frozen=True)
class PlantChoice:
    """Outcome of :func:`plant_choice_for`: the plant, and how its discretisation was chosen -- a Hill
    plant's harmonics, or a :class:`ModelPlant`'s propagator steps (``None`` when fixed by ``steps``)."""

    plant: Any
    harmonics: Optional[HarmonicsChoice] = None
    steps: Optional[StepsChoice] = None


def plant_choice_for(definition: Any, orbit: PeriodicOrbit, lin: LinearizedPeriodicSystem,
                     config: Optional[TuningConfig], *, steps: Optional[int] = None) -> PlantChoice:
    """:func:`plant_for` with the record of the harmonic choice (``tune --model`` reports it)."""
    if uses_hill(lin, config):
        if steps is not None:
            raise ValueError(f"--steps: model {definition.name} is evaluated by Hill's method (its harmonics are "
                             "chosen at the centre of the gain ranges): there are no propagator steps to set")
        if config is None:
            raise ValueError("plant_for: a Hill plant needs the tuning configuration (its ranges and tolerance)")
        choice = hill_choice(lin, orbit, config)
        return PlantChoice(choice.plant, choice)
    plant = ModelPlant(lin, orbit)
    if steps is not None:
        return PlantChoice(dataclasses.replace(plant, n_steps=int(steps)))
    if config is None or not orbit.drive_names:
        return PlantChoice(plant)
    sc = propagator_choice(plant, config)
    return PlantChoice(sc.plant, steps=sc)


def plant_for(definition: Any, orbit: PeriodicOrbit, lin: LinearizedPeriodicSystem, config: Optional[TuningConfig],
              *, steps: Optional[int] = None) -> MeasuredPlant:
    """The tuning plant of a model at one Omega: the one rule of ``tune``, ``study`` and ``chart --model``.

    Parameters
    ----------
    definition : ModelDefinition
        The model (its name is used in messages only: the method is decided by :func:`uses_hill`).
    orbit, lin
        Its periodic orbit and linearisation (gains 0) at the Omega.
    config : TuningConfig or None
        The tuning ranges and tolerance: the discretisation (Hill harmonics, propagator steps) is
        chosen at the centre of the ranges to a fraction of the tolerance.  ``None`` (a model
        without drives: nothing to tune): the :class:`ModelPlant` with ``steps`` or its default.
    steps : int, optional
        Fixed propagator steps of a :class:`ModelPlant` (``chart --steps``) instead of the rule.

    Returns
    -------
    HillModelPlant or ModelPlant
        Both :class:`stability.gains.Plant` and :class:`stability.gains.MeasuredPlant`.

    Raises
    ------
    ValueError
        ``steps`` given for a model evaluated by Hill's method (it has no propagator steps).
    """
    return plant_choice_for(definition, orbit, lin, config, steps=steps).plant


def whole_spectrum(orbit: PeriodicOrbit, omega: float, kp: Sequence[float], kd: Sequence[float]) -> dict:
    """The spectral radius of the whole linearisation at the tuned gains, beside the tuned response.

    A model file's tuning response is the dominant multiplier of the drive modes and the first
    bending mode (:data:`MODEL_RESPONSE`); the spectrum of a finite-element model also holds
    high-frequency axial / bending modes of the mesh that the joint gains barely move (e.g. the
    two-link at 2 elements per link and its tuned gains: an axial pair at 22 kHz with |rho| = 0.557,
    0.860 at 4 elements -- not converged under mesh refinement).  Reported, never hidden: the
    largest modulus of the whole spectrum (:func:`linearize.analysis.analyze` on the same orbit,
    frozen-modal frame) with its mode label, frequency and estimate.

    Returns
    -------
    dict
        ``response``, ``spectral_radius_all``, ``spectral_radius_all_mode``,
        ``spectral_radius_all_frequency_hz``, ``spectral_radius_all_error_estimate`` (a stable
        JSON contract of ``tune --model`` and the study's two-link section; the estimate is the
        relative error estimate of that multiplier itself, not the largest over all moduli),
        ``verdict_detail`` (:func:`stability.verdict.judge_floquet` with the mode labels).
    """
    from linearize.analysis import analyze

    r = analyze(None, omega, kp=kp, kd=kd, orbit=orbit)
    top = r.modes[0] if r.modes else None
    v = r.verdict
    rho = float(r.floquet.spectral_radius)
    return {"response": MODEL_RESPONSE,
            "spectral_radius_all": rho,
            "spectral_radius_all_mode": top.mode if top is not None else None,
            "spectral_radius_all_frequency_hz": top.frequency_hz if top is not None else None,
            "spectral_radius_all_error_estimate": float(v.spectral_radius_error / rho) if rho > 0 else None,
            "verdict_detail": v.to_dict()}


def mesh_dependence(resolve: Any, omega: float, kp: Sequence[float], kd: Sequence[float], elements: int) -> list:
    """The whole loop's spectral radius of a built-in model at ``elements`` and ``2 elements``.

    ``resolve(e) -> (definition, build options)`` gives the model with ``e`` elements
    (e.g. :func:`flexstab.options.resolve_model_definition`).

    Returns
    -------
    list of dict
        Per mesh: ``elements``, ``spectral_radius``, ``mode``, ``frequency_hz``, ``error_estimate``
        (relative, that multiplier's own), ``verdict``.
    """
    from linearize.analysis import analyze

    out = []
    for e in (int(elements), 2 * int(elements)):
        definition, options = resolve(e)
        r = analyze(definition, omega, kp=kp, kd=kd, **options)
        v = r.verdict
        out.append({"elements": e, "spectral_radius": v.spectral_radius, "mode": v.spectral_radius_label,
                    "frequency_hz": v.spectral_radius_frequency_hz,
                    "error_estimate": v.spectral_radius_error / v.spectral_radius if v.spectral_radius else None,
                    "verdict": v.verdict})
    return out


def response_note(tuned: float, covers: str, verdict: dict, mesh: Optional[list] = None) -> Optional[str]:
    """Words for a tuned response below the whole loop's spectral radius (``None`` when they are equal);
    ``covers`` names the tuned modes (e.g. :data:`MODEL_RESPONSE_MODES`).

    E.g. "the drive modes decay at 0.30 per period; axial 9 at 22.1 kHz decays at 0.557, set by the mesh
    and by structural damping the model does not have".
    """
    rho = verdict.get("spectral_radius")
    if rho is None or not rho > tuned * (1.0 + 1e-9):
        return None
    label = verdict.get("spectral_radius_mode") or "another mode"
    f = verdict.get("spectral_radius_frequency_hz")
    where = ""
    if f:
        where = f" at {f / 1e3:.3g} kHz" if f >= 1e3 else f" at {f:.3g} Hz"
    text = (f"the {covers} decay at {tuned:.3g} per period; {label}{where} decays at {rho:.3g} per "
            f"period (the whole loop's spectral radius)")
    if mesh and len(mesh) > 1:
        a, b = mesh[0], mesh[1]
        text += (f"; {b['spectral_radius']:.3g} ({b['mode']}) at {b['elements']} elements instead of "
                 f"{a['elements']}")
        if abs(b["spectral_radius"] - a["spectral_radius"]) > 1e-3 * a["spectral_radius"]:
            text += ": set by the mesh and by structural damping the model does not have (--damping)"
    return text
