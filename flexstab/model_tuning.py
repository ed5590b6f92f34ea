"""Tuning the PD gains of a model file: the library half of ``flexstab tune --model`` and of
``flexstab study --model``.

:func:`tune_model_plant` tunes the ``2 N`` gains of a plant with ``N`` drives (one ``(kp, kd)`` pair per
drive, :class:`DrivesObjective`) and, for a time-stepping plant, checks the tuned response with twice the
propagator steps; :func:`factor_ranges` gives the factors' names and ranges, :func:`build_plant` the
plant of a model name and :func:`unreachable_mode` the multiplier no drive can move.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, Optional

from flexstab.options import gain_pairs

if TYPE_CHECKING:
    from taguchi.tuning import TuningConfig

logger = logging.getLogger(__name__)

__all__ = ["build_plant", "DrivesObjective", "FallbackRecorder", "factor_ranges", "RESTART_WIDTH", "tune_model_plant",
           "unreachable_mode"]


def build_plant(model: str, cfg, omega: float, constants: str, elements=None, damping=None):
    """The plant object (``with_gains(kp, kd)``) for the chosen model (``damping``: a
    :class:`~mbs_models.damping.DampingSpec`, default ``cfg.damping``)."""
    damping = damping if damping is not None else getattr(cfg, "damping", None)
    given = damping is not None and damping.given
    if model not in ("reduced", "exudyn"):
        from flexstab.options import resolve_model_definition
        from linearize.analysis import model_plant

        definition, options = resolve_model_definition(model, cfg, elements,
                                                       **(damping.build_options() if given else {}))
        plant = model_plant(definition, omega, **options)
        if not plant.drives:
            raise ValueError(f"the model {model!r} has no drives: there are no PD gains to tune")
        return plant
    if model == "reduced":
        if given:
            raise ValueError("--damping applies to the Exudyn and model-file models, not to --model reduced")
        from mbs_models.reduced import ReducedModel

        return ReducedModel(omega=omega, params=cfg.manipulator, constants=constants)
    from linearize.link_floquet import exudyn_plant  # the Exudyn linearisation

    extra = {}
    if given:
        from mbs_models.damping import material_damping_values

        p = cfg.manipulator
        b, a = material_damping_values(damping.material, p.bending_stiffness, p.axial_stiffness, damping.bending,
                                       damping.axial)
        extra = {"bending_damping": b, "axial_damping": a}
    # prepared: the linearisation is interpolated, solved and balanced once, not per gain pair
    return exudyn_plant(cfg.manipulator, omega=omega, elements=elements or cfg.elements, prepared=True, **extra)


class DrivesObjective:
    """``(kp1, kd1, kp2, kd2, ...) -> response`` of a plant with one (kp, kd) pair per drive.

    The response is the plant's own ``spectral_measure(kp, kd)`` (for a model
    file: the modulus of the dominant labelled multiplier, drive modes and the
    first bending mode), called with one gain per drive.
    """

    def __init__(self, plant) -> None:
        if not callable(getattr(plant, "spectral_measure", None)):
            raise ValueError("plant must provide spectral_measure(kp, kd)")
        self.plant = plant

    def __call__(self, gains) -> float:
        g = [float(v) for v in gains]
        if len(g) % 2:
            raise ValueError(f"gains must be (kp, kd) pairs per drive, got {len(g)} values")
        return float(self.plant.spectral_measure(g[0::2], g[1::2]))


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
    e.g. from :func:`propagator_steps`) is tuned
    with :class:`DrivesObjective`; at the tuned gains its response with ``2 n`` propagator steps is
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

    from taguchi.tuning import recentre, taguchi_tune

    from flexstab.plants import MAX_TUNING_STEPS

    from linearize.hill_plant import HillModelPlant

    if isinstance(plant, HillModelPlant):  # no propagator steps to refine: one pass
        return taguchi_tune(DrivesObjective(plant), tcfg, executor=executor, progress=progress), plant, []
    n_drives = len(plant.drives)
    passes: list = []
    full_cfg = tcfg
    while True:
        res = taguchi_tune(DrivesObjective(plant), tcfg, executor=executor, progress=progress)
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
        if (not res.converged or 4.0 / 3.0 * abs(r2 - res.spectral_radius) <= 0.25 * tcfg.effective_tolerance
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
    centre = [0.5 * (lo + hi) for lo, hi in tcfg.factor_ranges]
    n = len(orbit.drive_names)
    kp, kd = centre[0::2], centre[1::2]
    r = analyze(None, omega, kp=kp, kd=kd, orbit=orbit)
    top = r.modes[0] if r.modes else None
    if top is None or drive_movable(top, orbit.drive_names):
        return None
    j = int(np.argmin(np.abs(np.asarray(r.floquet.multipliers) - r.dominant_multiplier)))
    tuned = r.modes[j]
    shares = ", ".join(f"{k} {v:.2f}" for k, v in top.get("drive_shares", {}).items())
    gains = ", ".join(f"{name} = {v:.4g}" for name, v in zip(tcfg.names, centre))
    msg = (f"note: at the range centre ({gains}) the closed loop's largest multiplier |rho| = "
           f"{float(r.floquet.spectral_radius):.5g} belongs to '{top['mode']}', a mode no drive moves "
           f"(drive shares {shares}): PD gains cannot bring max|rho| below it; tuning the dominant multiplier "
           f"of the modes the drives move ('{tuned['mode']}', |rho| = {abs(r.dominant_multiplier):.5g})")
    return {"modulus": float(r.floquet.spectral_radius), "mode": top["mode"],
            "drive_shares": dict(top.get("drive_shares", {})), "gains": centre[: 2 * n],
            "tuned_mode": tuned["mode"], "tuned_modulus": float(abs(r.dominant_multiplier)), "message": msg}
